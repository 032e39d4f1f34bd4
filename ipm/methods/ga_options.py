"""Settings of the genetic path's objective (:class:`GAOptions`), per profile, and what they decide.

The GA's own settings (budget, populations, statistics) are ``ipm.optim.ga_settings.GASettings``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Literal

from ipm.errors import UserError
from ipm.generators.base import Generator
from ipm.settings import UNIT, Settings, at_least


@dataclass(frozen=True)
class GAOptions(Settings):
    """Settings of the GA path's objective (the GA's own settings: ``ipm.optim.ga_settings.GASettings``)."""

    KIND = "GA option"

    impostor: Annotated[int, at_least(16)] = 128
    """Impostor size in pixels (square)."""
    margin: Annotated[float, UNIT] = 0.12
    """Space around the reference's bounding box in the impostor window, per side, as a share of
    the box's longer side."""
    supersample: Annotated[int, at_least(1)] = 1
    """Rays per impostor pixel and axis (majority rule beyond 1)."""
    n_stripes: int = 16
    """Stripes of the tree similarity (over the object's height)."""
    regularisers: tuple[str, ...] | None = ("leaf_density",)
    """Multipliers of ``ipm.losses.tree`` (trees). ``branch_density`` is left out by default: a
    crowned tree shows a few dozen branch pixels, and their ratio is noise (0.67-0.81 for the true
    tree_2 and copies of it with one unrelated gene changed)."""
    graph_vertices: Annotated[int, at_least(1)] | None = None
    """Target branch-graph vertex count (the paper's recommended regulariser); None: off."""
    placement: Literal["mask", "box", "none"] = "mask"
    """Multiplier that sees the pose (trees): ``mask`` (IoU of the reference's and the candidate's
    silhouettes in the input view), ``box`` (IoU of their pixel bounding boxes) or ``none``."""
    turns: Annotated[int, at_least(1)] = 4
    """Views of a tree around its vertical axis (1: the input view only;
    ``ipm.losses.tree_objective.Objective``)."""
    turn_weight: Annotated[float, UNIT] = 1.0
    """``w`` of the symmetry multiplier ``1 - w (1 - s)``, ``s`` the turned views' mean IoU."""
    max_graph_vertices: Annotated[int, at_least(1)] | None = 4000
    """Complexity budget (trees): multiply by ``min(1, max_graph_vertices / n)`` for a branch graph
    of ``n`` vertices. Without it the search drifts to the most complex trees the generator makes
    (a tree_1 run ended at 46k graph vertices, 1.5M triangles at the output's detail, 112 ms per
    evaluation), as the paper warns; 4000 is above every preset (700-2700). None: off."""
    lod: int = 0
    """Generator level of detail during the search."""
    output_lod: int | None = None
    """Level of detail of the written mesh; None: ``lod`` for trees (the trees generator's turtle
    takes more sub-steps at finer levels, which can reshape a tree with strong curvature: a fit
    0.4 wide at level 0 was 1.4 wide at level 2), 1 for others (as the differentiable path)."""
    loss: Literal["auto", "tree", "silhouette"] = "auto"
    """``tree``, ``silhouette`` or ``auto`` (the tree loss for a plant generator, ``Generator.plant``)."""
    labels: Literal["auto", "semantic", "rgb"] = "auto"
    """Where the tree loss's reference labels come from: ``semantic`` (the views' label images),
    ``rgb`` (the photos' colours inside the masks, ``ipm.io.semantic.labels_from_rgb``, as the
    paper does in simple cases) or ``auto`` (label images where the views have them)."""


PROFILE_OPTIONS = {
    "smoke": GAOptions(impostor=64, n_stripes=8),
    "default": GAOptions(),
    "paper": GAOptions(impostor=256),
}
"""Objective settings per profile (the GA's budget comes from ``ipm.optim.ga_settings.GA_PROFILES``)."""


def get_options(profile: str, **overrides) -> GAOptions:
    """The profile's objective settings with ``overrides`` (``UserError`` for unknown names)."""
    if profile not in PROFILE_OPTIONS:
        raise UserError(f"unknown profile {profile!r} (known: {', '.join(PROFILE_OPTIONS)})")
    return PROFILE_OPTIONS[profile].updated(**overrides)


def uses_tree_loss(generator: Generator, options: GAOptions) -> bool:
    """Whether ``options.loss`` picks the tree loss for ``generator`` (``UserError`` if it cannot)."""
    tree = generator.plant if options.loss == "auto" else options.loss == "tree"
    if tree and not generator.plant:
        raise UserError(f"the tree loss needs a plant generator (parts branch and foliage), not "
                        f"{generator.name!r} ({', '.join(generator.part_names)})")
    return tree


def output_lod(generator: Generator, options: GAOptions) -> int:
    """Level of detail of the written mesh (``GAOptions.output_lod``)."""
    if options.output_lod is not None:
        return int(options.output_lod)
    return options.lod if generator.plant else min(1, max(generator.lods))
