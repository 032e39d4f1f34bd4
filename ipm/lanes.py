"""Independent tries of a search run side by side on the process's threads, with the results, the
trace and the render seeds of running them one after another, to the bit.

A search's evaluations draw their render seeds in order (``ipm.search.objective.Objective.seeds``)
and grow the JAX renderer's span budgets as its meshes need (``ipm.render.edges.EdgeRenderer``);
both would follow the threads' timing if tries simply ran at once. Here each try (a :class:`Task`)
runs with the seeds it would draw after the tries before it (a task says how many it draws; one that
rewinds an objective's seeds draws from the first, as each finalist's refinement does), on its
own copy of every budget table it reads (:func:`table`), its trace rows held back (:func:`later`).
The tries are then taken in order: one whose budgets were those the tries before it leave behind
is kept as it ran and its rows written; any other runs again, alone, on the budgets as they stand
(a budget grows a few times a fit). XLA runs two programs at once on two threads, each program's
numbers its own whatever runs beside it (``docs/design``, "Tries side by side").
"""
from __future__ import annotations

import functools
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

_LOCAL = threading.local()
_MISSING = object()


@dataclass(frozen=True)
class Task:
    """One try: ``fn()`` runs it; ``draws`` maps each object whose render seeds it draws (its
    ``calls`` the count drawn so far) to how many it draws."""

    fn: Callable[[], Any]
    draws: dict = field(default_factory=dict)
    rewinds: tuple = ()
    """Objects of ``draws`` the task rewinds (:func:`rewind`) before it draws any seed of them (a
    draw before is an error): its seeds of them start at 0 whatever ran before, and it leaves them
    at its count."""


class _Context:
    """What one task runs with: its seeds' cursors, its copies of the budget tables, what it grew,
    its held trace rows."""

    def __init__(self, bases: dict, rewound: frozenset = frozenset()):
        self.cursors = dict(bases)
        self.first = dict(bases)
        self.rewound = rewound  # ids of the objects whose seeds the task starts again at 0
        self.pending = set(rewound)  # those not yet rewound: no draws of them before
        self.tables: dict = {}  # id(shared table) -> (shared, the task's copy)
        self.journal: list = []  # (shared table, key, budget used, budget after)
        self.held: list = []  # (fn, args)


def _current() -> _Context | None:
    return getattr(_LOCAL, "context", None)


def draw(owner, n: int) -> np.ndarray | None:
    """Within a task, the next ``n`` render seeds of ``owner`` (None outside tasks: ``owner`` draws
    its own). A draw the task did not declare is an error in the caller's plan."""
    context = _current()
    if context is None:
        return None
    if id(owner) not in context.cursors:
        raise RuntimeError("a task drew render seeds of an objective it did not declare")
    if id(owner) in context.pending:
        raise RuntimeError("a task drew render seeds of an objective before it rewound them")
    start = context.cursors[id(owner)]
    context.cursors[id(owner)] = start + n
    return np.arange(start, start + n)


def rewind(owner) -> bool:
    """Within a task that declared ``owner`` rewound, its next render seed of ``owner`` is 0 again
    (True); outside tasks False: ``owner`` rewinds itself."""
    context = _current()
    if context is None:
        return False
    if id(owner) not in context.rewound:
        raise RuntimeError("a task rewound render seeds it did not declare rewound")
    context.cursors[id(owner)] = 0
    context.pending.discard(id(owner))
    return True


def table(shared: dict) -> dict:
    """The budget table to read and grow: ``shared`` itself outside tasks, else the task's copy."""
    context = _current()
    if context is None:
        return shared
    return context.tables.setdefault(id(shared), (shared, dict(shared)))[1]


def note(shared: dict, key, used, after) -> None:
    """Within a task, that an evaluation ran with budget ``used`` of ``shared[key]`` and left ``after``."""
    context = _current()
    if context is not None:
        context.journal.append((shared, key, used, after))


def later(fn: Callable, *args) -> None:
    """``fn(*args)`` now outside tasks; within one, when the task is kept (trace rows, in order)."""
    context = _current()
    if context is None:
        fn(*args)
    else:
        context.held.append((fn, args))


class Lanes:
    """Runs lists of :class:`Task` on ``workers`` threads (one: in turn, as plain calls)."""

    def __init__(self, workers: int = 1):
        self.workers = max(1, int(workers))
        self._pool: ThreadPoolExecutor | None = None

    def map(self, tasks: list[Task]) -> list:
        """Every task's result, in order."""
        return self._results(tasks, lambda result: False, len(tasks))

    def first(self, tasks: list[Task], stop: Callable[[Any], bool]) -> list:
        """The tasks' results in order, up to and including the first for which ``stop`` holds
        (the later ones' runs, begun on spare threads, are dropped: as if never run)."""
        return self._results(tasks, stop, self.workers)

    def _results(self, tasks: list[Task], stop: Callable[[Any], bool], ahead: int) -> list:
        """:meth:`first`, with up to ``ahead`` tasks begun beyond the last one kept."""
        if self.workers == 1 or len(tasks) < 2 or _current() is not None:
            out = []
            for task in tasks:
                out.append(task.fn())
                if stop(out[-1]):
                    break
            return out
        bases, running = [], {}
        for task in tasks:
            for o in task.rewinds:
                running[id(o)] = 0
            bases.append({id(o): running.setdefault(id(o), o.calls) for o in task.draws})
            for o, n in task.draws.items():
                running[id(o)] += n
        pool = self._pool = self._pool or ThreadPoolExecutor(self.workers, thread_name_prefix="lane")
        futures, out = {}, []
        for i in range(min(ahead, len(tasks))):
            futures[i] = pool.submit(_run, tasks[i], bases[i])
        try:
            for i, task in enumerate(tasks):
                result, context = futures.pop(i).result()
                if not _fits(context):  # the budgets of an earlier try grew: run it again on them
                    result, context = _run(task, bases[i])
                _keep(task, context)
                out.append(result)
                if stop(result):
                    break
                if i + ahead < len(tasks):
                    futures[i + ahead] = pool.submit(_run, tasks[i + ahead], bases[i + ahead])
        finally:
            for future in futures.values():
                future.cancel()
            for future in futures.values():
                if not future.cancelled():
                    future.exception()  # waits; a dropped try's error is not the search's
        return out

    def close(self) -> None:
        """Stop the threads (a later call starts them again)."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


def _run(task: Task, bases: dict) -> tuple[Any, _Context]:
    _LOCAL.context = context = _Context(bases, frozenset(id(o) for o in task.rewinds))
    try:
        return task.fn(), context
    finally:
        _LOCAL.context = None


def _fits(context: _Context) -> bool:
    """Whether every budget the task used is the one the tries kept before it leave behind."""
    grown: dict = {}
    for shared, key, used, after in context.journal:
        mine = grown.setdefault(id(shared), {})
        value = mine[key] if key in mine else shared.get(key, _MISSING)
        if value is not _MISSING and value != used:
            return False
        mine[key] = after
    return True


def _keep(task: Task, context: _Context) -> None:
    """The task's budgets, seeds drawn and held rows made the search's own."""
    for o, n in task.draws.items():
        if context.cursors[id(o)] - context.first[id(o)] != n:
            raise RuntimeError(f"a task drew {context.cursors[id(o)] - context.first[id(o)]} render seeds, "
                               f"not the {n} it declared")
    for shared, key, _, after in context.journal:
        shared[key] = after
    for o, n in task.draws.items():
        o.calls = n if o in task.rewinds else o.calls + n
    for fn, args in context.held:
        fn(*args)


def once(fn: Callable) -> Callable:
    """``functools.cache`` whose value is made once even when threads ask for it at once (a vertex
    program is a key of the renderer's budgets: two made at once would be two keys)."""
    cached, lock = functools.cache(fn), threading.RLock()

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with lock:
            return cached(*args, **kwargs)

    return wrapper
