"""The buildings generator's parameter table: parts, roof kinds, every parameter with its range
and default, the largest counts, and the walls' height that the mesh, the facades and the roof
split share."""
from __future__ import annotations

from ipm.generators.base import make_spec

PARTS = ("walls", "windows", "frames", "roof", "door", "balconies")
WALLS, WINDOWS, FRAMES, ROOF, DOOR, BALCONIES = range(len(PARTS))
FLAT, GABLE, HIP = range(3)
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
    ("roof_thickness", 0.02, 0.08, False, 0.04), ("hip_ratio", 0.2, 1.0, False, 0.6),
    ("parapet_height", 0.01, 0.1, False, 0.04),
    # balconies (entrance facade)
    ("balcony_depth", 0.05, 0.25, False, 0.12), ("balcony_width", 0.2, 1.0, False, 0.5),
    ("balcony_thickness", 0.015, 0.05, False, 0.025), ("railing_height", 0.05, 0.14, False, 0.1),
    # chimney (position as a share of the footprint)
    ("chimney_x", -0.4, 0.4, False, 0.25), ("chimney_z", -0.4, 0.4, False, 0.0),
    ("chimney_size", 0.04, 0.15, False, 0.08), ("chimney_height", 0.05, 0.4, False, 0.15),
    # discrete structure
    ("floors", 1, 8, True, 2), ("windows_front", 0, 8, True, 3), ("windows_back", 0, 8, True, 3),
    ("windows_left", 0, 8, True, 2), ("windows_right", 0, 8, True, 2), ("entrances", 1, 3, True, 1),
    ("window_split", 0, 2, True, 1), ("roof_type", 0, 2, True, GABLE), ("balconies", 0, 2, True, 0),
    ("balcony_start", 1, 7, True, 1), ("chimney", 0, 1, True, 0), ("steps", 0, 3, True, 1),
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
