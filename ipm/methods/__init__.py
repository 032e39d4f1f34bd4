"""Reconstruction methods, registered by name; baselines register here too.

A method is a callable ``(views_path, out_dir, **options) -> None`` that writes at least
``out_dir/mesh.ply`` (world frame) and ``out_dir/timing.json``.
"""
from ipm.registry import Registry

METHODS: Registry = Registry("method")

from ipm.methods import diff  # noqa: E402,F401  (fills the registry)
