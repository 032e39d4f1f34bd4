"""Tries side by side (``ipm.lanes``): the seeds, budgets, results and held rows of running them one
after another, whatever the threads' timing."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from ipm import lanes
from ipm.lanes import Lanes, Task


class Drawer:
    """A stand-in for an objective: draws render seeds in order and keeps a budget table, grown as a
    renderer's is where a "mesh" needs more than it has."""

    def __init__(self):
        self.calls, self.budgets, self.rows = 0, {}, []

    def seeds(self, n: int) -> np.ndarray:
        drawn = lanes.draw(self, n)
        if drawn is not None:
            return drawn
        self.calls += n
        return np.arange(self.calls - n, self.calls)

    def rewind(self) -> None:
        if not lanes.rewind(self):
            self.calls = 0

    def evaluate(self, need: int, key: str = "k") -> tuple[int, int]:
        """(seed, budget run with): the budget starts at 4, grows to twice the need past it."""
        seed = int(self.seeds(1)[0])
        table = lanes.table(self.budgets)
        used = table.setdefault(key, 4)
        budget = used if need <= used else 2 * need
        table[key] = budget
        lanes.note(self.budgets, key, used, budget)
        lanes.later(self.rows.append, (seed, budget))
        return seed, budget


def _tasks(drawer: Drawer, needs: list[list[int]], pause: float = 0.0) -> list[Task]:
    def task(i: int, ns: list[int]) -> Task:
        def run():
            if pause and i % 2 == 0:
                time.sleep(pause)  # the even tries finish last
            return [drawer.evaluate(n) for n in ns]
        return Task(run, {drawer: len(ns)})
    return [task(i, ns) for i, ns in enumerate(needs)]


@pytest.mark.parametrize("needs", [
    [[1, 2], [3], [1, 1, 1], [2]],          # nothing grows
    [[1, 9], [3], [30, 1], [2], [5, 5]],    # budgets grow in the first and third tries: later tries run again
])
def test_side_by_side_gives_the_one_after_another_results(needs):
    serial, side = Drawer(), Drawer()
    expected = Lanes(1).map(_tasks(serial, needs))
    got = Lanes(2).map(_tasks(side, needs, pause=0.02))
    assert got == expected
    assert (side.calls, side.budgets, side.rows) == (serial.calls, serial.budgets, serial.rows)
    assert side.calls == sum(map(len, needs))


def test_tries_that_rewind_draw_from_the_first_seed_each_as_one_after_another():
    """A try declared to rewind its objective starts its draws at seed 0 whatever ran before, and
    leaves the objective at its own count: a search's finalists refined side by side."""
    needs = [[1, 2, 9], [3, 1, 1], [30, 1], [2]]

    def tasks(drawer):
        def task(ns):
            def run():
                drawer.rewind()
                return [drawer.evaluate(n) for n in ns]
            return Task(run, {drawer: len(ns)}, (drawer,))
        return [task(ns) for ns in needs]

    serial, side = Drawer(), Drawer()
    serial.calls = side.calls = 7
    expected = Lanes(1).map(tasks(serial))
    got = Lanes(2).map(tasks(side))
    assert got == expected and [[seed for seed, _ in r] for r in got] == [[0, 1, 2], [0, 1, 2], [0, 1], [0]]
    assert (side.calls, side.budgets, side.rows) == (serial.calls, serial.budgets, serial.rows)
    assert side.calls == 1
    with pytest.raises(RuntimeError, match="did not declare rewound"):
        Lanes(2).map([Task(lambda: side.rewind(), {side: 0}) for _ in range(2)])
    early = [Task(lambda: side.evaluate(1), {side: 1}, (side,)) for _ in range(2)]
    with pytest.raises(RuntimeError, match="before it rewound"):
        Lanes(2).map(early)


def test_first_keeps_the_tries_up_to_the_first_that_stops_and_nothing_of_the_rest():
    needs = [[1], [2], [50], [3], [4]]
    serial, side = Drawer(), Drawer()

    def stop(result):
        return result[-1][1] > 4  # the first try that grew the budget

    expected = Lanes(1).first(_tasks(serial, needs), stop)
    got = Lanes(2).first(_tasks(side, needs, pause=0.02), stop)
    assert got == expected and len(got) == 3
    assert (side.calls, side.budgets, side.rows) == (serial.calls, serial.budgets, serial.rows) == (3, {"k": 100}, [
        (0, 4), (1, 4), (2, 100)])


def test_a_draw_a_task_did_not_declare_is_an_error():
    drawer, other = Drawer(), Drawer()
    tasks = [Task(lambda: other.evaluate(1), {drawer: 1}), Task(lambda: drawer.evaluate(1), {drawer: 1})]
    with pytest.raises(RuntimeError, match="did not declare"):
        Lanes(2).map(tasks)
    short = [Task(lambda: drawer.evaluate(1), {drawer: 2}), Task(lambda: drawer.evaluate(1), {drawer: 1})]
    with pytest.raises(RuntimeError, match="not the 2 it declared"):
        Lanes(2).map(short)


def test_tries_run_at_once_on_two_threads():
    """Two tries that each wait for the other can only finish side by side."""
    both = threading.Barrier(2, timeout=5)
    tasks = [Task(lambda: both.wait() is not None) for _ in range(2)]
    side = Lanes(2)
    try:
        assert side.map(tasks) == [True, True]
    finally:
        side.close()


def test_once_makes_a_value_once_for_threads_asking_at_once():
    made = []

    @lanes.once
    def make(key):
        time.sleep(0.02)
        made.append(key)
        return object()

    out = []
    threads = [threading.Thread(target=lambda: out.append(make("a"))) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert made == ["a"] and len({id(o) for o in out}) == 1
