"""Reconstruction methods, registered by name; baselines register here too.

A method is a callable ``(views, out_dir, profile=, seed=, progress=, n_input_views=,
**options) -> dict`` (``views``: a ``transforms.json`` path or ``Views`` already read) that writes at least ``out_dir/mesh.ply`` (world frame) and
``out_dir/timing.json``, atomically. ``method`` attaches what the pipeline needs to know:
the table label, the view layout it reads (``ipm.synth.LAYOUTS``), whether it takes a
procedural generator (and whether that must be differentiable), and an optional per-generator
preparation stage whose file the method then reads as ``prepared=`` (the GA's gene statistics).
"""
from ipm.registry import Registry

METHODS: Registry = Registry("method")


def method(name: str, label: str, layout: str = "hemi", uses_generator: bool = False,
           differentiable_only: bool = False, prepare=None, seeded: bool = True):
    """Register a method under ``name``; ``label`` is the table's row label, with ``{views}``
    standing for "1 view" / "N views". ``prepare(generator, out_path, profile=, seed=, progress=)``,
    if given, writes a file per generator and seed (a cached pipeline stage) that the method takes
    as ``prepared=out_path``. ``seeded=False`` marks a method without random choices: the
    pipeline runs it once per case instead of once per seed."""

    def deco(fn):
        fn.label, fn.layout, fn.uses_generator = label, layout, uses_generator
        fn.differentiable_only, fn.prepare, fn.seeded = differentiable_only, prepare, seeded
        return METHODS.register(name)(fn)

    return deco


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


from ipm.methods import diff, ga  # noqa: E402,F401  (fill the registry)
import baselines  # noqa: E402,F401  (the baselines register into the same registry)
