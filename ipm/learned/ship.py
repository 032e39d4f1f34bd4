"""Make the weights shipped with the package: ``python -m ipm.learned.ship [GENERATOR ...]``.

The same code and budget as the workflow's preparation stage (``ipm.learned.train.prepare``, the
default profile, seed 0), written to ``ipm/learned/weights/GENERATOR.json``, so that
``ipm reconstruct --method learned`` or ``--start learned`` on a photo needs no training first.
"""
from __future__ import annotations

import sys

from ipm.learned.propose import SHIPPED
from ipm.learned.train import prepare

SHIPPED_GENERATORS = ("dishes", "buildings")


def main(argv: list[str]) -> None:
    from ipm.runtime import configure_threads

    configure_threads(1, "cpu")  # the workflow's preparation runs at one thread: the same numbers
    for name in argv or SHIPPED_GENERATORS:
        info = prepare(name, SHIPPED / f"{name}.json", profile="default", seed=0, progress=True)
        print(f"{name}: {info['seconds']:.0f} s, held-out {info['held_out']}, mean prediction {info['mean_prediction']}")


if __name__ == "__main__":
    main(sys.argv[1:])
