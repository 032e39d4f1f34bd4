"""Make the preparations shipped with the package: ``python -m ipm.ship [METHOD/GENERATOR ...]``.

Each is the workflow's preparation stage of a method (``METHODS[method].prepare``: the learned
regressor and its camera-hidden variant, the occupancy network, the GA's gene statistics) run
with the default profile, seed 0 and one thread, as the ``prepare`` rule runs it, and written
where the method's catalogue entry says (``Method.shipped``). The default workflow config reads
these files (``prepared: shipped``) instead of training in the run, so its learned rows are the
same on every machine; the benchmark config trains them in the run (``prepared: run``).
"""
from __future__ import annotations

import sys
import time

SHIPPED = {"learned": ("dishes", "buildings"), "learned_photo": ("dishes", "buildings"),
           "occnet": ("dishes", "buildings"), "ga": ("trees",)}
"""Per method with a preparation stage, the generators whose preparation ships."""


def shipped_names() -> list[str]:
    """Every shipped preparation as ``METHOD/GENERATOR``."""
    return [f"{m}/{g}" for m, gens in SHIPPED.items() for g in gens]


def ship(name: str) -> dict:
    """Make the shipped preparation ``METHOD/GENERATOR`` (the default profile, seed 0); its facts."""
    from ipm.errors import UserError
    from ipm.methods import METHODS

    method, _, generator = name.partition("/")
    if name not in shipped_names():
        raise UserError(f"unknown shipped preparation {name!r} (known: {', '.join(shipped_names())})")
    path = METHODS[method].shipped_path(generator)
    path.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    info = METHODS[method].prepare(generator, path, profile="default", seed=0, progress=True) or {}
    return {"name": name, "seconds": round(time.perf_counter() - t0, 1),
            **{k: info[k] for k in ("held_out", "mean_prediction") if k in info}}


def main(argv: list[str]) -> None:
    from ipm.runtime import configure_threads

    configure_threads(1, "cpu")  # the workflow's preparation runs at one thread: the same numbers
    for name in argv or shipped_names():
        print(ship(name))


if __name__ == "__main__":
    main(sys.argv[1:])
