"""The one pose convention of a reconstruction, and the NumPy yaw rotation (numpy only).

World vertices are ``scale * R_y(yaw) R_x(tilt_x) R_z(tilt_z) v + translation`` for the object's
vertices ``v`` (object frame: y up, lowest point at y = 0; docs/design, "Scene convention").
``R_y`` turns right-handed about the world's vertical +y axis (:func:`yaw_matrix`): +x goes
towards -z. params.json describes a pose by :data:`POSE_KEYS`: ``yaw``, ``tilt_x``, ``tilt_z``
(radians), ``translation`` (3 numbers, world units) and ``scale``. Both paths write it alike:
the differentiable one decodes its genes ``(yaw, tilt_x, tilt_z, dx, dy, dz, log_scale)``
(``ipm.problem.Problem.decode``), the genetic one its four pose genes with the tilts at 0
(``ipm.methods.ga_genome.Genome.world_mesh``); ``ipm.synth`` turns the cases' ground truths and
``ipm.metrics.align`` the alignment by the same ``R_y``.
"""
from __future__ import annotations

import math

import numpy as np

POSE_KEYS = ("yaw", "tilt_x", "tilt_z", "translation", "scale")
"""Keys of params.json's ``pose``, in the order they are written."""


def yaw_matrix(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` radians about the world's vertical (+y) axis, right-handed, (3, 3)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
