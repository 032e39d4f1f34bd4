"""Reconstruction methods, registered by name; baselines register here too.

A method is a callable ``(views_path, out_dir, profile=, seed=, progress=, n_input_views=,
**options) -> dict`` that writes at least ``out_dir/mesh.ply`` (world frame) and
``out_dir/timing.json``, atomically. ``method`` attaches what the pipeline needs to know:
the table label, the view layout it reads (``ipm.synth.LAYOUTS``) and whether it takes a
procedural generator.
"""
from ipm.registry import Registry

METHODS: Registry = Registry("method")


def method(name: str, label: str, layout: str = "hemi", uses_generator: bool = False):
    """Register a method under ``name``; ``label`` is the table's row label, with ``{views}``
    standing for "1 view" / "N views"."""

    def deco(fn):
        fn.label, fn.layout, fn.uses_generator = label, layout, uses_generator
        return METHODS.register(name)(fn)

    return deco


def row_label(name: str, views: int) -> str:
    """Table label of method ``name`` run on ``views`` views."""
    return METHODS[name].label.format(views=f"{views} view" if views == 1 else f"{views} views")


from ipm.methods import diff, ga  # noqa: E402,F401  (fill the registry)
import baselines  # noqa: E402,F401  (the baselines register into the same registry)
