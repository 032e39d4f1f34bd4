"""Baselines: general-purpose reconstruction methods, declared in the catalogue ``ipm.methods.METHODS``.

Each subpackage implements one or more methods and writes its mesh in the world frame of the
input views, so the same 64-view metric scores it.
"""
