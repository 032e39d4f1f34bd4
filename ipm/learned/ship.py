"""Make the weights shipped with the package: ``python -m ipm.learned.ship [NAME ...]``.

The same code and budget as the workflow's preparation stages (``ipm.learned.train.prepare`` and
``prepare_photo``, the default profile, seed 0), written to ``ipm/learned/weights/NAME.json``
(NAME: a generator, or GENERATOR_photo for the camera-hidden variant; default all), so that
``ipm reconstruct --method learned`` or the learned start on a photo needs no training first.
"""
from __future__ import annotations

import sys

from ipm.learned.propose import shipped_path
from ipm.learned.train import prepare

SHIPPED_GENERATORS = ("dishes", "buildings")


def main(argv: list[str]) -> None:
    from ipm.runtime import configure_threads

    configure_threads(1, "cpu")  # the workflow's preparation runs at one thread: the same numbers
    names = argv or [f"{g}{suffix}" for g in SHIPPED_GENERATORS for suffix in ("", "_photo")]
    for name in names:
        generator, hidden = name.removesuffix("_photo"), name.endswith("_photo")
        info = prepare(generator, shipped_path(generator, hidden), profile="default", seed=0, progress=True,
                       camera_hidden=hidden)
        print(f"{name}: {info['seconds']:.0f} s, held-out {info['held_out']}, mean prediction {info['mean_prediction']}")


if __name__ == "__main__":
    main(sys.argv[1:])
