"""The plans laid over a footprint: a building's extent, and each other plan (rectangle, L, T, U,
with and without the annex) made to cover it, as the plan move tries them (``ipm.search.moves.plan``)."""
from __future__ import annotations

import numpy as np

from ipm.generators.buildings.table import L_PLAN, PLANS, RECTANGLE, T_PLAN, U_PLAN, WINGS

SHARE_MAIN = 0.6
"""The main wing's share of the extent's depth where the plan has back wings (the rest theirs)."""
SHARE_ANNEX = 0.25
"""The annex's share of the extent's width."""
ANNEX_DEPTH = 0.6
"""The annex's width across it as a share of the main wing's depth."""
BACK_WIDTH = {RECTANGLE: 0.45, L_PLAN: 0.45, T_PLAN: 0.45, U_PLAN: 0.3}
"""A back wing's width as a share of the main wing's, by plan (each of a U's two; a rectangle's unused)."""
WING_PITCH = 0.8
"""A laid wing's roof height as a share of the main roof's (a wing is narrower than the main wing)."""


def extent(p: dict) -> tuple[float, float, float, float]:
    """The object-frame footprint (x0, x1, z0, z1) of a buildings parameter set by name: the main
    wing, the back wings its plan has (towards -z) and the annex (towards +x), as
    ``ipm.generators.buildings.footprint.wing_frame`` lays them."""
    hx, hz = p["width"] / 2, p["depth"] / 2
    plan, annex = int(round(p["template"])), int(round(p["annex"]))
    back = max([p["wing1_length"]] * (plan >= L_PLAN) + [p["wing2_length"]] * (plan == U_PLAN) + [0.0])
    return -hx, hx + (p["wing3_length"] if annex else 0.0), -hz - back, hz


def laid(p: dict, plan: int, annex: int) -> tuple[dict, np.ndarray]:
    """``p`` with plan ``plan`` and annex ``annex`` laid over its extent (the shares above; every
    wing at the main wing's storeys and roof kind), and the object-frame move (3,) that puts the
    new extent where the old one was (before the generator's bounds clip it)."""
    x0, x1, z0, z1 = extent(p)
    width, depth = x1 - x0, z1 - z0
    q = dict(p, template=plan, annex=annex)
    q["width"] = (1 - SHARE_ANNEX) * width if annex else width
    q["depth"] = SHARE_MAIN * depth if plan != RECTANGLE else depth
    for k in (1, 2):
        q[f"wing{k}_length"] = (1 - SHARE_MAIN) * depth
        q[f"wing{k}_width"] = BACK_WIDTH[plan] * q["width"]
        q[f"wing{k}_shift"] = 0.0
    q["wing3_length"], q["wing3_width"], q["wing3_shift"] = SHARE_ANNEX * width, ANNEX_DEPTH * q["depth"], 0.0
    for k in WINGS:
        q[f"wing{k}_floors"], q[f"wing{k}_roof"] = p["floors"], p["roof_type"]
        q[f"wing{k}_roof_height"] = WING_PITCH * p["roof_height"]
    n0, n1, m0, m1 = extent(q)
    return q, np.array([(x0 + x1 - n0 - n1) / 2, 0.0, (z0 + z1 - m0 - m1) / 2])


def plan_name(plan: int, annex: int) -> str:
    """A plan's name in the trace: ``L``, ``U + annex``, ..."""
    return PLANS[plan] + (" + annex" if annex else "")
