"""The buildings generator's parameter table: parts, roof kinds, wing templates, every parameter
with its range and default, the largest counts, and the walls' height that the mesh, the facades
and the roof split share."""
from __future__ import annotations

import numpy as np

from ipm.generators.base import make_spec

PARTS = ("walls", "windows", "frames", "roof", "door", "balconies")
WALLS, WINDOWS, FRAMES, ROOF, DOOR, BALCONIES = range(len(PARTS))
ROOF_KINDS = ("flat", "gabled", "hipped", "half-hipped", "pyramidal", "skillion", "saltbox", "gambrel", "mansard")
"""The roof kinds (``roof_type`` and each wing's ``wingK_roof``), by OpenStreetMap's ``roof:shape`` names."""
ROOF_WEIGHTS = np.sqrt([20, 59, 11, 1.4, 3.6, 2.7, 0.8, 0.5, 0.3])
ROOF_WEIGHTS = ROOF_WEIGHTS / ROOF_WEIGHTS.sum()
"""The sampler's roof kinds (in ``ROOF_KINDS``' order): the shares of about 7 million roofs
tagged in OpenStreetMap (gabled 59 %, flat 20 %, hipped 11 %, pyramidal 3.6 %, skillion 2.7 %,
half-hipped 1.4 %, saltbox 0.8 %, gambrel 0.5 %, mansard 0.3 %) tempered by a square root, so
that the rare kinds are drawn often enough to be learned."""
FLAT, GABLE, HIP, HALF_HIP, PYRAMID, SKILLION, SALTBOX, GAMBREL, MANSARD = range(len(ROOF_KINDS))
PLANS = ("rectangle", "L", "T", "U")
"""The wing templates (``template``, its values' names): the main wing alone, or one wing on its
back flush with its right end (L), at its middle (T), or two flush with both ends (U); ``annex``
adds a wing on the right end as well."""
RECTANGLE, L_PLAN, T_PLAN, U_PLAN = range(len(PLANS))
WINGS = (1, 2, 3)
"""Wing numbers: 1 and 2 on the main wing's back (the templates'), 3 on its right end (the annex)."""
MIN_PIER = 0.03
"""Least wall between two openings and above an opening (object units)."""
GLASS = 0.003
"""Thickness of the glass and door leaves, set just in front of the recess's back."""
RAIL = 0.01
"""Thickness of balcony railings and parapets."""

_SPEC_ROWS = [
    # footprint and storeys
    ("width", 0.6, 2.0, False, 1.2), ("depth", 0.5, 1.6, False, 0.9),
    ("floor_height", 0.25, 0.45, False, 0.32), ("ground_extra", 0.0, 0.15, False, 0.04),
    # windows
    ("window_width", 0.06, 0.3, False, 0.14), ("window_height", 0.08, 0.3, False, 0.18),
    ("window_sill", 0.03, 0.12, False, 0.08), ("window_inset", 0.01, 0.05, False, 0.025),
    ("window_margin", 0.03, 0.3, False, 0.1), ("side_window_scale", 0.5, 1.5, False, 1.0),
    ("ground_window_scale", 0.7, 2.0, False, 1.0), ("ground_window_height", 0.08, 0.35, False, 0.2),
    ("frame_width", 0.005, 0.025, False, 0.012), ("frame_depth", 0.004, 0.03, False, 0.01),
    ("mullion_width", 0.004, 0.015, False, 0.008),
    # entrances
    ("door_width", 0.08, 0.3, False, 0.14), ("door_height", 0.15, 0.4, False, 0.26),
    ("canopy_depth", 0.02, 0.15, False, 0.06), ("canopy_overhang", 0.0, 0.06, False, 0.03),
    ("step_height", 0.01, 0.05, False, 0.02), ("step_depth", 0.02, 0.08, False, 0.04),
    # top of the walls and roof
    ("cornice_height", 0.01, 0.06, False, 0.03), ("cornice_offset", 0.0, 0.05, False, 0.02),
    ("roof_height", 0.05, 0.8, False, 0.35), ("roof_overhang", 0.0, 0.15, False, 0.05),
    ("roof_thickness", 0.02, 0.08, False, 0.04), ("hip_ratio", 0.0, 1.0, False, 0.6),
    ("parapet_height", 0.01, 0.1, False, 0.04), ("knee_height", 0.3, 0.85, False, 0.6),
    ("knee_run", 0.08, 0.45, False, 0.2), ("ridge_offset", 0.15, 0.7, False, 0.4),
    # balconies (entrance facade)
    ("balcony_depth", 0.05, 0.25, False, 0.12), ("balcony_width", 0.2, 1.0, False, 0.5),
    ("balcony_thickness", 0.015, 0.05, False, 0.025), ("railing_height", 0.05, 0.14, False, 0.1),
    # chimney (position as a share of the footprint)
    ("chimney_x", -0.4, 0.4, False, 0.25), ("chimney_z", -0.4, 0.4, False, 0.0),
    ("chimney_size", 0.04, 0.15, False, 0.08), ("chimney_height", 0.05, 0.4, False, 0.15),
    # wings: across the side they stand on, out from it, moved along it; roof height
    *((f"wing{k}_{name}", lo, hi, False, default) for k in WINGS for name, lo, hi, default in
      (("width", 0.3, 1.2, 0.6), ("length", 0.2, 1.2, 0.6), ("shift", -0.4, 0.4, 0.0), ("roof_height", 0.05, 0.8, 0.3))),
    # discrete structure
    ("floors", 1, 8, True, 2), ("windows_front", 0, 8, True, 3), ("windows_back", 0, 8, True, 3),
    ("windows_left", 0, 8, True, 2), ("windows_right", 0, 8, True, 2), ("entrances", 1, 3, True, 1),
    ("window_split", 0, 2, True, 1), ("roof_type", 0, len(ROOF_KINDS) - 1, True, GABLE),
    ("balconies", 0, 2, True, 0), ("balcony_start", 1, 7, True, 1), ("chimney", 0, 1, True, 0),
    ("steps", 0, 3, True, 1), ("template", 0, len(PLANS) - 1, True, RECTANGLE), ("annex", 0, 1, True, 0),
    *((f"wing{k}_{name}", lo, hi, True, default) for k in WINGS for name, lo, hi, default in
      (("floors", 1, 8, 1), ("roof", 0, len(ROOF_KINDS) - 1, GABLE), ("windows", 0, 8, 2), ("end_windows", 0, 8, 1))),
]
DISCRETE = [row[0] for row in _SPEC_ROWS if row[3]]


def _largest(name: str) -> int:
    return int(dict((row[0], row[2]) for row in _SPEC_ROWS)[name])


MAX_FLOORS, MAX_WINDOWS, MAX_ENTRANCES, MAX_STEPS = (_largest(n) for n in ("floors", "windows_front", "entrances", "steps"))


SPEC = make_spec(_SPEC_ROWS)


def wall_top(p):
    """Height of the walls' top (the storeys and the ground floor's extra), ``p`` a parameter's
    value by name: one formula for the mesh, the facades and the roof split."""
    return p("floors") * p("floor_height") + p("ground_extra")


def wing_top(p, k: int):
    """Height of wing ``k``'s walls: its own storeys at the main wing's floor height."""
    return p(f"wing{k}_floors") * p("floor_height") + p("ground_extra")
