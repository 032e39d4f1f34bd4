"""Pipeline steps called by the thin Snakemake scripts: logging, threads, one library call each.

Each step sends stderr (progress bars, warnings) to the rule's log file and sets the
thread count of XLA and Dr.Jit to the rule's ``threads`` before anything heavy is imported.
"""
from __future__ import annotations

import contextlib
import sys
from pathlib import Path


@contextlib.contextmanager
def _logged(log: str | None, threads: int, mitsuba: bool = False, device: str = "cpu", quick_compile: bool = False):
    from ipm.runtime import configure_threads

    configure_threads(threads, device, quick_compile)
    stream = open(log, "w") if log else None
    old = sys.stderr
    if stream:
        sys.stderr = stream
    try:
        if mitsuba:
            from ipm.runtime import set_mitsuba_variant

            set_mitsuba_variant(device, threads)
        yield
    finally:
        sys.stderr = old
        if stream:
            stream.close()


def synth_step(case: str, transforms: str, views: int, res: int, spp: int, layout: str = "hemi",
               threads: int = 1, log=None):
    with _logged(log, threads, mitsuba=True):
        from ipm.synth import synthesize

        synthesize(case, Path(transforms).parent, n_views=views, res=res, spp=spp, layout=layout)


def degrade_step(src: str, dst: str, slug: str, seed: int, log=None):
    """The views folder ``src`` with every mask degraded by the degradation called ``slug``
    (``ipm.degrade``), at ``dst``: a mask row's input."""
    with _logged(log, 1):
        from ipm.degrade import by_slug, degrade_views

        degrade_views(src, dst, by_slug(slug), seed)


def reference_step(case: str, reference: str, gallery: str | None = None, masks: str | None = None,
                   n_views: int = 64, res: int = 256, log=None):
    """The case's reference mesh and truth, its gallery sheet (the report's first row) and its
    masks from the metric's ``n_views`` cameras at ``res`` px (cast once for every evaluation)."""
    with _logged(log, 1, mitsuba=gallery is not None):
        from ipm.synth import write_reference

        write_reference(case, Path(reference).parent)
        if masks:
            from ipm.metrics.silhouette import write_reference_masks

            write_reference_masks(reference, masks, n_views, res)
        if gallery:
            from ipm.render.gallery import gallery_sheet

            gallery_sheet(reference, reference, gallery)


def prepare_step(method: str, generator: str, out: str, profile: str, seed: int, threads: int = 1, log=None):
    """A method's per-generator preparation (the GA's gene statistics), cached by the DAG."""
    with _logged(log, threads):
        from ipm.methods import METHODS

        METHODS[method].prepare(generator, out, profile=profile, seed=seed, progress=True)


def reconstruct_step(method: str, transforms: str, mesh: str, generator: str, profile: str, seed: int,
                     n_input_views: int, prepared: str | None = None, settings: dict | None = None,
                     threads: int = 1, log=None, device: str = "cpu"):
    """One reconstruction, ours or a baseline (the generator goes only to methods that take one,
    ``prepared`` only to methods with a preparation stage; ``settings`` override the profile's), with
    JAX and Mitsuba on ``device`` (the config's: cpu or cuda)."""
    from ipm.methods import METHODS

    fn = METHODS[method]
    with _logged(log, threads, mitsuba=True, device=device, quick_compile=fn.compiles):
        from ipm.io import write_json
        from ipm.runtime import job_clock, machine_info

        extra = {"generator": generator} if fn.takes_generator else {}
        if prepared:
            extra["prepared"] = prepared
        with job_clock() as clock:
            fn(transforms, Path(mesh).parent, profile=profile, seed=seed, n_input_views=n_input_views, **extra,
               **dict(settings or {}))
        write_json(Path(mesh).parent / "machine.json", {**machine_info(threads, device), **clock})


def reference_line_step(name: str, reference: str, truth: str, mesh: str, threads: int = 1, log=None):
    with _logged(log, threads):
        from ipm.io import write_json
        from ipm.reference_lines import write_reference_line
        from ipm.runtime import job_clock, machine_info

        with job_clock() as clock:
            write_reference_line(name, reference, Path(mesh).parent, truth=truth)
        write_json(Path(mesh).parent / "machine.json", {**machine_info(threads), **clock})


def evaluate_step(reference: str, truth: str, run: str, metrics: str, preview: str, row: dict, seed: int,
                  n_views: int, res: int, grid: int, gallery: str | None = None, views: str | None = None,
                  reference_masks: str | None = None, threads: int = 1, log=None):
    """Metrics of the reconstruction in folder ``run`` (with parameter recovery where the truth and
    the fit share a generator, its counts those the input ``views`` folder shows), its gallery
    sheet, and ``row.json`` beside them (table label, kind, case split and class, seed, wall time,
    the machine it ran on, note). A run that recorded a failure (``failed`` in its info.json) gets
    no metrics, only the reason."""
    with _logged(log, threads, mitsuba=gallery is not None):
        import json

        from ipm.cases import case_split
        from ipm.io import write_json
        from ipm.metrics.evaluate import evaluate_files, failure_files
        from ipm.runtime import machine_line

        folder = Path(run)
        mesh, timing = folder / "mesh.ply", folder / "timing.json"
        info = json.loads((folder / "info.json").read_text()) if (folder / "info.json").exists() else {}
        params = json.loads((folder / "params.json").read_text()) if (folder / "params.json").exists() else None
        case = json.loads(Path(truth).read_text())
        if info.get("failed"):
            failure_files(info["failed"], metrics, preview)
        else:
            evaluate_files(reference, mesh, metrics, n_views=n_views, res=res, grid=grid, preview_path=preview,
                           truth=case, params=params, views=views, reference_masks=reference_masks)
        if gallery:
            from ipm.render.gallery import gallery_sheet

            gallery_sheet(str(mesh), reference, gallery)
        seconds = json.loads(timing.read_text()).get("seconds")
        job = json.loads((folder / "machine.json").read_text()) if (folder / "machine.json").exists() else None
        machine = machine_line(job) if job else "not recorded"
        note = f"failed: {info['failed']}" if info.get("failed") else info.get("note", "")
        write_json(Path(metrics).parent / "row.json", {**row, "split": case_split(case), "generator": case["generator"],
                                                       "seed": seed, "seconds": seconds,
                                                       "cpu_seconds": (job or {}).get("cpu_seconds"),
                                                       "machine": machine, "note": note})


def texture_step(run: str, views: str, out: str, n_input: int, appearance: str, row: dict, seed: int,
                 threads: int = 1, log=None):
    """Appearance scores (``ipm.metrics.texture``) of the result in folder ``run``, rendered by
    ``appearance``, against the colour views ``views`` (the held layout: view 0 the case's input
    view), with the row's label, input count and the case's split: ``texture.json``."""
    with _logged(log, threads, mitsuba=True):
        import json

        from ipm.cases import case_split
        from ipm.io import write_json
        from ipm.metrics.texture import score_result

        scores = score_result(run, Path(views) / "transforms.json", appearance)
        case = json.loads((Path(views) / "ground_truth.json").read_text())
        write_json(out, {**row, "case": case["name"], "split": case_split(case), "seed": seed, "inputs": n_input,
                         **scores})


def parts_preview_step(reference: str, transforms: str, mesh: str, png: str, threads: int = 1, log=None):
    with _logged(log, threads, mitsuba=True):
        from ipm.render.preview import parts_sheet

        parts_sheet(reference, mesh, transforms, png)


def texture_table_step(scores: list[str], table: str, markdown: str, log=None):
    """The appearance table of the textured runs (``ipm.table.texture_table``) as CSV and markdown."""
    with _logged(log, 1):
        from ipm.io.atomic import atomic_path
        from ipm.table import texture_markdown, texture_table

        df = texture_table(scores)
        with atomic_path(table) as tmp:
            df.to_csv(tmp, index=False)
        with atomic_path(markdown) as tmp:
            tmp.write_text(texture_markdown(df))


def table_step(metrics: list[str], table: str, wide: str, summary: str, markdown: str, cases=None, log=None):
    with _logged(log, 1):
        from ipm.table import build_table

        build_table(metrics, table, wide, summary, markdown, cases=cases)


def report_step(table: str, wide: str, summary: str, metrics: list[str], out: str, config: dict, input_dirs: dict,
                benchmarks: list[str] = (), textures: str | None = None, log=None):
    with _logged(log, 1):
        from reports.build import build_report

        build_report(table_csv=table, wide_csv=wide, summary_csv=summary, metrics=metrics, out_html=out,
                     config=config, input_dirs=input_dirs, benchmarks=list(benchmarks), texture_csv=textures)


def report_check_step(html: str, out_dir: str, rows: list[str], log=None):
    """Open the report in headless Chromium: console errors, every row, images and 3D views;
    screenshots and ``check.json`` into ``out_dir`` (written whole, or not at all)."""
    with _logged(log, 1):
        from ipm.io import atomic_dir
        from reports.browser import check_report

        with atomic_dir(out_dir) as tmp:
            check_report(html, str(tmp), rows)
