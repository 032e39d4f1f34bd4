"""Pipeline steps called by the thin Snakemake scripts: logging, threads, one library call each.

Each step sends stderr (progress bars, warnings) to the rule's log file and sets the
thread count of XLA and Dr.Jit to the rule's ``threads`` before anything heavy is imported.
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path


@contextlib.contextmanager
def _logged(log: str | None, threads: int, mitsuba: bool = False):
    from ipm.runtime import configure_threads

    configure_threads(threads)
    stream = open(log, "w") if log else None
    old = sys.stderr
    if stream:
        sys.stderr = stream
    try:
        if mitsuba:
            from ipm.runtime import set_mitsuba_variant

            set_mitsuba_variant("cpu", threads)
        yield
    finally:
        sys.stderr = old
        if stream:
            stream.close()


def synth_step(case: str, transforms: str, views: int, res: int, spp: int, threads: int = 1, log=None):
    with _logged(log, threads, mitsuba=True):
        from ipm.synth import synthesize

        synthesize(case, Path(transforms).parent, n_views=views, res=res, spp=spp)


def reconstruct_step(method: str, transforms: str, mesh: str, generator: str, profile: str, seed: int,
                     n_input_views: int, threads: int = 1, log=None):
    with _logged(log, threads, mitsuba=True):
        from ipm.methods import METHODS

        METHODS[method](transforms, Path(mesh).parent, generator=generator, profile=profile, seed=seed,
                        n_input_views=n_input_views)


def reference_line_step(name: str, reference: str, mesh: str, threads: int = 1, log=None):
    with _logged(log, threads):
        from ipm.reference_lines import write_reference_line

        write_reference_line(name, reference, Path(mesh).parent)


def evaluate_step(reference: str, mesh: str, timing: str, metrics: str, preview: str, row: dict,
                  n_views: int, res: int, grid: int, threads: int = 1, log=None):
    """Metrics of one reconstruction, and ``row.json`` (table label, kind, wall time) beside them."""
    with _logged(log, threads):
        import json

        from ipm.io import write_json
        from ipm.metrics.evaluate import evaluate_files

        evaluate_files(reference, mesh, metrics, n_views=n_views, res=res, grid=grid, preview_path=preview)
        seconds = json.loads(Path(timing).read_text()).get("seconds")
        write_json(Path(metrics).parent / "row.json", {**row, "seconds": seconds})


def parts_preview_step(reference: str, transforms: str, mesh: str, png: str, threads: int = 1, log=None):
    with _logged(log, threads, mitsuba=True):
        from ipm.render.preview import parts_sheet

        parts_sheet(reference, mesh, transforms, png)


def table_step(metrics: list[str], table: str, wide: str, log=None):
    with _logged(log, 1):
        from ipm.table import build_table

        build_table(metrics, table, wide)


def report_step(table: str, wide: str, metrics: list[str], out: str, config: dict, log=None):
    with _logged(log, 1):
        from reports.build import build_report

        build_report(table_csv=table, wide_csv=wide, metrics=metrics, out_html=out, config=config)
