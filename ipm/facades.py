"""Reading storeys and windows per facade off a window mask, by rectifying each facade the view
sees (the counts a person reads off a photo of a house).

From one view the silhouette says nothing about windows, and the window-mask loss compares
counts badly: a window count one off trades against the windows' widths and margins, and a few
Adam steps per count value do not settle which is right. The mask itself shows
them: sampled on the facade plane of the current estimate (pose and footprint, which the silhouette
fixes well), each storey is a row of window blobs and each facade's blobs per row are its count.
"""
from __future__ import annotations

import numpy as np

from ipm.generators.base import SEEN_COS
from ipm.render.cameras import project

GAP = 0.025
"""Gaps in the window mask narrower than this (object units) are mullions or anti-aliasing, not
the wall between two windows or two storeys: mullions are at most 0.015 wide, and the least wall
between two openings is 0.03 plus two frames (``ipm.generators.buildings``)."""
GAP_PIXELS = 1.5
"""... nor than this many image pixels (a window two pixels apart from the next is not resolved)."""
MIN_INSIDE = 0.8
"""Share of a facade's samples that must fall inside the image and the object's silhouette for
its reading to count (else the estimate's pose is too far off to read it)."""
DENSITY = 2.0
"""Samples per image pixel of a rectified facade."""
MARKER_PIXELS = 2.0
"""A marker (a door) this many pixels wide or more shows in a view's semantic image."""
WINDOW_PIXELS = 4.0
"""A facade shows its windows in a view when their class covers this many of the view's pixels on
it or more (a 2 x 2 blob; less is a speck, not a window a person could count)."""


def runs(on: np.ndarray, min_gap: int) -> list[tuple[int, int]]:
    """Runs ``[start, end)`` of True in ``on`` (1-D) after closing gaps shorter than ``min_gap``."""
    idx = np.flatnonzero(on)
    if not len(idx):
        return []
    breaks = np.flatnonzero(np.diff(idx) > min_gap)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]]) + 1
    return list(zip(starts.tolist(), ends.tolist()))


def rectify(image: np.ndarray, c2w: np.ndarray, fov_x: float, origin, along, length: float, top: float,
            density: float = DENSITY) -> tuple[np.ndarray, float, float]:
    """Sample ``image`` (..., H, W) on the world rectangle ``origin + a along + y up`` (``a``
    centred over ``length``, ``y`` in [0, ``top``]; ``along`` scaled to world size) at about
    ``density`` samples per image pixel. Returns the grid (..., rows from the ground up, columns
    along the facade; NaN outside the image) and the samples per object unit across and up."""
    origin, along = np.asarray(origin, float), np.asarray(along, float)
    up = np.array([0.0, np.linalg.norm(along), 0.0])  # the same world scale as along
    h, w = image.shape[-2:]
    corners = project(np.stack([origin - 0.5 * length * along, origin + 0.5 * length * along,
                                origin - 0.5 * length * along + top * up]), c2w, fov_x, w, h)
    n_a = int(np.clip(density * np.linalg.norm(corners[1] - corners[0]), 8, 4096))
    n_y = int(np.clip(density * np.linalg.norm(corners[2] - corners[0]), 8, 4096))
    a = (np.arange(n_a) + 0.5) / n_a * length - 0.5 * length
    y = (np.arange(n_y) + 0.5) / n_y * top
    points = origin + a[None, :, None] * along + y[:, None, None] * up
    px = project(points.reshape(-1, 3), c2w, fov_x, w, h)
    col, row = np.floor(px[:, 0]).astype(int), np.floor(px[:, 1]).astype(int)
    inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
    grid = np.full(image.shape[:-2] + (len(px),), np.nan)
    grid[..., inside] = image[..., row[inside], col[inside]]
    return grid.reshape(image.shape[:-2] + (n_y, n_a)), n_a / length, n_y / top


def count_rows_and_windows(grid: np.ndarray, per_unit_a: float, per_unit_y: float,
                           samples_per_pixel: float = DENSITY) -> tuple[int, int]:
    """(storeys, windows per storey) of a rectified window mask (rows from the ground up): the
    rows of window blobs, and the most common number of blobs in a row (ties: the higher rows')."""
    grid = np.nan_to_num(grid) > 0.5
    gap_a = max(GAP * per_unit_a, GAP_PIXELS * samples_per_pixel)
    gap_y = max(GAP * per_unit_y, GAP_PIXELS * samples_per_pixel)
    share = grid.mean(1)
    least = samples_per_pixel  # a blob less than a pixel across is a speck, not a window
    rows = [r for r in runs(share > 0.1 * share.max(initial=0.0), int(np.ceil(gap_y))) if r[1] - r[0] >= least]
    counts = []
    for y0, y1 in rows:
        band = grid[y0:y1].any(0)
        counts.append(sum(1 for a0, a1 in runs(band, int(np.ceil(gap_a))) if a1 - a0 >= least))
    if not counts:
        return 0, 0
    top = max(set(counts), key=lambda v: (counts.count(v), max(i for i, c in enumerate(counts) if c == v)))
    return len(rows), int(top)


def _facade_frames(sides: dict, to_world, views):
    """Per facade of ``sides`` (``Generator.facades``): its foot's centre and along direction in
    the world, the view facing it most squarely, that view's cosine to its normal, length and height."""
    out = {}
    for name, (origin, along, normal, length, top) in sides.items():
        o = to_world(np.asarray(origin)[None])[0]
        d_along = to_world(np.asarray(origin + along)[None])[0] - o
        d_normal = to_world(np.asarray(origin + normal)[None])[0] - o
        to_cam = views.c2w[:, :3, 3] - o
        cos = (to_cam @ d_normal) / np.linalg.norm(to_cam, axis=1) / np.linalg.norm(d_normal)
        best = int(np.argmax(cos))
        out[name] = (o, d_along, best, float(cos[best]), length, top)
    return out


def marker_reading(generator, x, to_world, views, marker_masks: np.ndarray) -> tuple[float, float]:
    """The turn about +y (radians; 0, a quarter or a half) that the views' ``generator.marker``
    class (buildings: the door, on the front only) says the estimate ``x`` posed by ``to_world``
    needs, and the evidence for it, as a share of the views' pixels: the turn brings the marker's
    facade to the seen facade that shows most of the marker (the evidence: the marker's pixels),
    or is a half turn when the views show no marker anywhere though a typical one (the
    generator's defaults) on the estimate's facade would show (``MARKER_PIXELS`` wide or more past
    the reveal that hides it at an angle; the evidence: the pixels it would cover). From one view
    the long sides of a house have one silhouette, and a square house four; where the turn
    changes the silhouette, the reading forks the estimate into both sides
    (``ipm.search.moves.counts``)."""
    sides = generator.facades(x)
    frames = _facade_frames(sides, to_world, views)
    own = generator.marker[1]
    shown = {}
    for name, (o, d_along, best, cos, length, top) in frames.items():
        if name != own and cos > SEEN_COS:
            grid, _, _ = rectify(marker_masks[best], views.c2w[best], views.fov_x, o, d_along, length, top)
            shown[name] = int(np.sum(np.nan_to_num(grid) > 0.5))
    n_own = np.asarray(sides[own][2], float)
    if shown and max(shown.values()) > 0:
        n_to = np.asarray(sides[max(shown, key=shown.get)][2], float)
        return float(np.arctan2(np.cross(n_own, n_to)[1], n_own @ n_to)), float(np.mean(marker_masks > 0.5))
    o, d_along, best, cos, _, _ = frames[own]
    # no marker pixel anywhere pins the estimate's own marker (the loss shrinks it out of sight),
    # so the question is whether a typical one (the generator's defaults) would show there
    width, recess, height = generator.marker_extent(generator.spec.default)
    ends = project(np.stack([o, o + d_along]), views.c2w[best], views.fov_x, views.width, views.height)
    per_unit = np.linalg.norm(ends[1] - ends[0])  # image pixels per object unit along the facade, foreshortened
    tan = np.sqrt(max(1.0 - cos**2, 0.0)) / max(cos, 1e-6)
    wide = (width - recess * tan) * per_unit  # the reveal hides the rest
    if cos > SEEN_COS and wide > MARKER_PIXELS and not marker_masks.any():
        pixels = wide * height * per_unit / max(cos, 1e-6)  # upright, so not foreshortened as the width is
        return float(np.pi), float(pixels / (views.width * views.height * len(marker_masks)))
    return 0.0, 0.0


def read_counts(generator, x: np.ndarray, to_world, seen: list[str], views, class_masks: np.ndarray,
                silhouettes: np.ndarray) -> dict[str, int]:
    """The counts the views' class masks show for the estimate ``x`` (physical parameters) posed
    by ``to_world`` (object points (k, 3) -> world): each facade (``generator.facades(x)``) among
    the ``seen`` counts (``Generator.seen_counts``) read in the view that faces it most squarely,
    unless that view sees less than ``MIN_INSIDE`` of it inside the silhouette; storeys from the
    facades with windows. Counts not read are left out."""
    found, storeys = {}, []
    for name, (o, d_along, best, _, length, top) in _facade_frames(generator.facades(x), to_world, views).items():
        if name not in seen:
            continue
        (sil, grid), per_a, per_y = rectify(np.stack([silhouettes[best], class_masks[best]]), views.c2w[best],
                                            views.fov_x, o, d_along, length, top)
        if np.mean(np.nan_to_num(sil) > 0.5) < MIN_INSIDE:
            continue
        n_rows, n_windows = count_rows_and_windows(grid, per_a, per_y)
        found[name] = n_windows
        if n_windows:
            storeys.append(n_rows)
    if storeys:
        found["floors"] = int(max(storeys))
    return found


def shown_counts(generator, x: np.ndarray, to_world, views, class_masks: np.ndarray) -> list[str]:
    """The count parameters (``generator.counts``) of the object ``x`` posed by ``to_world`` that
    the views' class masks show, so that a fit can read them: a facade's count when the view that
    faces it most squarely sees it (``SEEN_COS``) and either its class covers ``WINDOW_PIXELS`` or
    more there (rectified onto the facade) or it has none (a blank wall reads as none); the other
    counts (storeys) when some facade's windows show. The reveals hide a window's glass at an angle
    (building_d4's front, 65 degrees off, shows none of its seven), and with no window in sight the
    storeys of a wall of given height cannot be told."""
    facades, any_shown = [], False
    for name, (o, d_along, best, cos, length, top) in _facade_frames(generator.facades(x), to_world, views).items():
        if cos <= SEEN_COS:
            continue
        grid, _, _ = rectify(class_masks[best], views.c2w[best], views.fov_x, o, d_along, length, top)
        up = np.array([0.0, np.linalg.norm(d_along), 0.0])
        quad = project(np.stack([o - 0.5 * length * d_along, o + 0.5 * length * d_along,
                                 o + 0.5 * length * d_along + top * up, o - 0.5 * length * d_along + top * up]),
                       views.c2w[best], views.fov_x, views.width, views.height)
        area = 0.5 * abs(np.dot(quad[:, 0], np.roll(quad[:, 1], -1)) - np.dot(quad[:, 1], np.roll(quad[:, 0], -1)))
        pixels = float(np.nansum(grid)) / grid.size * area  # the facade's share in its class, in image pixels
        if pixels >= WINDOW_PIXELS:
            facades.append(name)
            any_shown = True
        elif x[generator.spec.index[name]] == 0:
            facades.append(name)
    return [n for n in generator.counts if n in facades or (n not in generator.facing and any_shown)]
