"""Baselines: general-purpose reconstruction methods, registered in ``ipm.methods.METHODS``.

Each subpackage registers one or more methods with ``ipm.methods.method`` and writes its mesh
in the world frame of the input views, so the same 64-view metric scores it.
"""
from baselines import colmap, diffsdf, visual_hull  # noqa: F401
