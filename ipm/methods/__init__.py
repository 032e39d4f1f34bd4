"""Reconstruction methods, ours and the baselines, declared by name: a light catalogue.

Importing this module loads no implementation (no JAX, Mitsuba or open3d), so Snakemake's parse
of the workflow reads the catalogue cheaply; a method's code is imported on its first call.

A method is a callable ``(views, out_dir, profile=, seed=, progress=, n_input_views=,
**options) -> dict`` (``views``: a ``transforms.json`` path or ``Views`` already read) that writes
at least ``out_dir/mesh.ply`` (world frame) and ``out_dir/timing.json``, atomically. Its entry
says what the pipeline needs to know: the table label, the view layout it reads
(``ipm.synth.LAYOUTS``), whether it takes a procedural generator (and whether that must be
differentiable), and an optional per-generator preparation stage whose file the method then
reads as ``prepared=`` (the GA's gene statistics). Adding one: its module, and a line below.
"""
from __future__ import annotations

import contextlib
import importlib
import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ipm.registry import Registry


def resolve(entry: str) -> Callable:
    """The object an entry ``"package.module:name"`` names (imported now)."""
    module, _, name = entry.partition(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class Method:
    """A catalogue entry: a method's name, row label, implementation and what the pipeline asks of it."""

    name: str
    label: str
    """The table's row label, with ``{views}`` standing for "1 view" / "N views"."""
    entry: str
    """``module:function`` of the implementation."""
    layout: str = "hemi"
    uses_generator: bool = False
    differentiable_only: bool = False
    learns_generator: bool = False
    """A baseline that learns a generator's class from its samples without fitting the program
    (the occupancy network): it takes ``generator=`` (and ``prepared=``) but is scored as a baseline."""
    prepare_entry: str | None = None
    """``module:function`` writing a file per generator and seed (a cached pipeline stage),
    ``prepare(generator, out_path, profile=, seed=, progress=)``; the method takes it as ``prepared=``."""
    shipped: str | None = None
    """``package:path`` of the preparation's file shipped with the package for a generator
    (``{generator}`` in the path): the default profile's, seed 0, made by ``python -m ipm.ship``."""
    seeded: bool = True
    """False for a method without random choices: the pipeline runs it once per case, not per seed."""
    length: int = 0
    """How long a run takes, in ranks (0 seconds, 1 a minute or two, 2 several minutes on one core):
    the workflow starts the longer ones first, so that no long job is left to end the run alone."""
    compiles: bool = False
    """A first run of a case spends most of its time compiling JAX programs that its other seeds'
    runs would compile again (a cup's smoke fit: 33 s cold, 5 s reading them back): the pipeline
    runs a case's other seeds after its first instead of beside it."""
    withholds_camera: bool = False
    """The diff path with the input's camera withheld (the photo rows): its start is the
    camera-hidden regressor's (``learned_photo``) where the profile asks for a learned camera."""
    appearance: str | None = None
    """``module:function(run, views)`` rendering a result folder's appearance at ``views``
    (``ipm.io.views.Views``) as linear RGB (n, H, W, 3) under the reference lighting: ours' painted
    textures, instant-NGP-style's radiance field. The workflow scores such rows' appearance
    (``ipm.metrics.texture``)."""
    scored_by: str = "iou_mean"
    """Table 1's headline metric for its rows: ``shape_iou`` where the camera is withheld (one
    uncalibrated photo fixes neither scale against distance nor a cup's lens), the world IoU beside it."""

    @property
    def takes_generator(self) -> bool:
        """Whether a run is passed the case's generator (ours, and baselines that learn its class)."""
        return self.uses_generator or self.learns_generator

    def __call__(self, *args, **kwargs) -> dict:
        if self.compiles:  # the last run's programs read from the start
            from ipm.read_ahead import read_ahead

            reading = read_ahead(f"{self.name}-{kwargs.get('generator', '')}")
        else:
            reading = contextlib.nullcontext()
        with reading:
            return resolve(self.entry)(*args, **kwargs)

    @property
    def prepare(self) -> Callable | None:
        return None if self.prepare_entry is None else resolve(self.prepare_entry)

    def shipped_path(self, generator: str) -> Path | None:
        """Where the shipped preparation of ``generator`` lies (whether or not it is there); None
        for a method that ships none. Nothing is imported but the package's parents."""
        if self.shipped is None:
            return None
        package, _, path = self.shipped.partition(":")
        spec = importlib.util.find_spec(package)
        return Path(list(spec.submodule_search_locations)[0]) / path.format(generator=generator)

    def shipped_file(self, generator: str) -> Path | None:
        """The shipped preparation of ``generator`` if the package has one, else None."""
        path = self.shipped_path(generator)
        return path if path is not None and path.is_file() else None


METHODS: Registry[Method] = Registry("method")


def declare(name: str, label: str, entry: str, **options) -> Method:
    """Add a method to the catalogue (a second entry of one name is an error)."""
    return METHODS.register(name)(Method(name, label, entry, **options))


def check_generator(name: str, generator: str) -> None:
    """``UserError`` unless method ``name`` can fit generator ``generator`` (the diff path needs a
    differentiable one)."""
    from ipm.errors import UserError
    from ipm.generators import get_generator

    if METHODS[name].differentiable_only and not get_generator(generator).differentiable:
        raise UserError(f"method {name!r} needs a differentiable generator; {generator!r} is not one "
                        f"(use the GA path: ga)")


def row_label(name: str, views: int) -> str:
    """Table label of method ``name`` run on ``views`` views."""
    return METHODS[name].label.format(views=f"{views} view" if views == 1 else f"{views} views")


_DIFF = dict(layout="hemi", uses_generator=True, differentiable_only=True, length=1, compiles=True)
declare("diff", "ours (diff, {views})", "ipm.methods.diff:run_diff", **_DIFF,
        appearance="ipm.metrics.texture:render_textured")
_PHOTO = dict(_DIFF, withholds_camera=True, scored_by="shape_iou")
declare("photo", "ours (diff, camera unknown, {views})", "ipm.methods.diff:run_photo", **_PHOTO)
declare("photo_fov", "ours (diff, camera unknown, FOV given, {views})", "ipm.methods.diff:run_photo_fov", **_PHOTO)
declare("photo_image", "ours (diff, photo, image only, {views})", "ipm.methods.diff:run_photo_image",
        **{**_PHOTO, "layout": "photo"})
declare("photo_masked", "ours (diff, photo, image + mask, {views})", "ipm.methods.diff:run_photo",
        **{**_PHOTO, "layout": "photo"})
declare("ga", "ours (GA, {views})", "ipm.methods.ga:run_ga", layout="hemi", uses_generator=True, length=2,
        prepare_entry="ipm.methods.ga:collect_generator_statistics", shipped="ipm.methods:prepared/ga_{generator}.json",
        appearance="ipm.metrics.texture:render_textured")
declare("learned", "learned regressor ({views})", "ipm.methods.learned:run_learned", **{**_DIFF, "length": 0},
        prepare_entry="ipm.learned.train:prepare", shipped="ipm.learned:weights/{generator}.json")
declare("learned_photo", "learned regressor (camera unknown, {views})", "ipm.methods.learned:run_learned_photo",
        **{**_DIFF, "length": 0}, scored_by="shape_iou", prepare_entry="ipm.learned.train:prepare_photo",
        shipped="ipm.learned:weights/{generator}_photo.json")
declare("diffsdf", "diffSDF-style ({views})", "baselines.diffsdf:run_diffsdf", layout="hemi")
declare("visual_hull", "visual hull ({views})", "baselines.visual_hull:run_visual_hull", layout="hemi", seeded=False)
declare("colmap_known", "COLMAP known poses ({views})", "baselines.colmap:run_colmap_known", layout="ring")
declare("colmap_sfm", "COLMAP SfM ({views})", "baselines.colmap:run_colmap_sfm", layout="ring")
declare("ngp", "instant-NGP-style ({views})", "baselines.ngp:run_ngp", layout="hemi", length=2,
        appearance="baselines.ngp:render_result")
declare("occnet", "occupancy network ({views})", "baselines.occnet:run_occnet", layout="hemi",
        learns_generator=True, prepare_entry="baselines.occnet:prepare",
        shipped="baselines.occnet:weights/{generator}.json")
