"""The paper's tree similarity function (section "Non-differentiable Case", "Tree Similarity Function").

The paper defines the loss between a generated tree and the reference image as

    Loss = TSim * prod_{c in C} min(c, c_ref) / max(c, c_ref)

where ``TSim`` compares semantic masks (background, branch, foliage) of the reference and of the
generated tree's impostor, and the optional multipliers compare characteristics ``c`` (number of
branch-graph vertices, height and width, average branch and leaf density, average leaf size).
That ``Loss`` is a similarity (1 = identical), so the value to *minimise* here is

    tree_loss = 1 - TSim * prod(multipliers)        (in [0, 1], 0 = identical).

**Stripes.** The image is cut into horizontal stripes (the paper: 20-30; the authors' impostors:
256 px cut into 16 px stripes, ``docs/design``, "Tree GA"); per stripe ``i`` the paper takes

- ``[a_i, d_i]`` crown borders: left edge of the leftmost and right edge of the rightmost
  column holding any branch or foliage pixel;
- ``[b_i, c_i]`` dense crown borders "(>75 % leaves pixels)": left edge of the leftmost and
  right edge of the rightmost column of which more than 75 % of the stripe's pixels are foliage
  (no such column: ``b_i = c_i`` = the middle of ``[a_i, d_i]``, an empty interval);
- ``B_i``, ``L_i``: branch and foliage pixels as a share of the stripe's crown box
  (stripe rows x ``[a_i, d_i]``);
- trunk or crown "according to the ratio B_i/L_i": trunk where ``B_i / L_i > 1``.

**Normalisation** (the paper's text says nothing; the authors' impostors are rescaled so that the
tree fills the texture, with its root centred): stripes split the object's bounding-box height
(so ``n`` stripes = image height / stripe height, each covering the same *relative* height in
both images), and horizontal positions are measured from the root (the centre of the branch
pixels in the lowest 2 % of the object) in units of the object's height. ``TSim`` thus compares
shape; size (height, width in pixels) is left to the multipliers.

**TSim** (the paper: "comparing the parameters a_i, b_i, c_i, d_i and B_i/L_i ratio for every
stripe"; the exact formula is not given, this is our reading). Per stripe, crown ``A = [a, d]``
and dense crown ``D = [b, c]`` are compared by a weighted Jaccard index, and the branch share
``r = B / (B + L)`` (a bounded form of ``B/L``) by its difference::

    s_i = (|A ∩ A'| + w |D ∩ D'|) * (1 - |r - r'|)        m_i = |A ∪ A'| + w |D ∪ D'|

(``w = 2``: dense crown counts three times, as in the authors' implementation). Stripes that are
trunk in either image form the trunk group ``T``, the other non-empty stripes the crown group
``K``; ``S_G = sum_G s_i / sum_G m_i`` and

    TSim = (1 - tau) S_K + tau S_T     (tau = 0.3; only the group present if one is empty),

so thin trunk stripes are not drowned by wide crown stripes. ``TSim`` is symmetric, in [0, 1],
and 1 exactly when both images have the same stripe features.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from ipm.errors import UserError
from ipm.io.semantic import BRANCH, FOLIAGE, check_labels
from ipm.losses.registry import LOSSES

DENSE_SHARE = 0.75
"""A column of a stripe is dense crown when more than this share of its pixels are foliage."""

ROOT_BAND = 0.02
"""Share of the object's height (at least one row) at its bottom where the root is located."""

REGULARISERS = ("graph_vertices", "height", "width", "branch_density", "leaf_density", "leaf_size")
"""The paper's regularisation characteristics, by name (see :func:`regularisation_multipliers`)."""


@dataclass(frozen=True, eq=False)
class StripeFeatures:
    """Per-stripe features of one label image (arrays of shape (n_stripes,), top stripe first)."""

    a: np.ndarray
    """Crown left border, from the root, in object heights."""
    b: np.ndarray
    """Dense crown left border (``a <= b``)."""
    c: np.ndarray
    """Dense crown right border (``b <= c <= d``)."""
    d: np.ndarray
    """Crown right border."""
    branch_share: np.ndarray
    """``B_i``: branch pixels / pixels of the stripe's crown box (0 for an empty stripe)."""
    leaf_share: np.ndarray
    """``L_i``: foliage pixels / pixels of the stripe's crown box (0 for an empty stripe)."""
    trunk: np.ndarray
    """True for trunk stripes (``B_i / L_i > trunk_ratio``), False for crown and empty ones."""
    empty: np.ndarray
    """True for stripes without object pixels (a gap in the object, or fewer rows than stripes)."""
    shape: tuple[int, int]
    """(H, W) of the label image."""
    bbox: tuple[int, int, int, int]
    """Object bounding box in pixels: (top, bottom, left, right), bottom and right exclusive."""
    root_x: float
    """Root position in pixels (column centres at i + 0.5)."""
    branch_density: float
    """Branch pixels / pixels of the object's bounding box."""
    leaf_density: float
    """Foliage pixels / pixels of the object's bounding box."""

    @property
    def n_stripes(self) -> int:
        return len(self.a)

    @property
    def height(self) -> int:
        """Object height in pixels."""
        return self.bbox[1] - self.bbox[0]

    @property
    def width(self) -> int:
        """Object width in pixels."""
        return self.bbox[3] - self.bbox[2]


def _n_stripes(height: int, stripe_height: int | None, n_stripes: int | None) -> int:
    if n_stripes is not None:
        if int(n_stripes) != n_stripes or n_stripes < 1:
            raise UserError(f"n_stripes must be a positive integer, got {n_stripes!r}")
        return int(n_stripes)
    if stripe_height is None or int(stripe_height) != stripe_height or stripe_height < 1:
        raise UserError(f"stripe_height must be a positive integer, got {stripe_height!r}")
    return max(1, round(height / stripe_height))


def stripe_features(labels: np.ndarray, stripe_height: int | None = 16, n_stripes: int | None = None,
                    *, trunk_ratio: float = 1.0) -> StripeFeatures:
    """The paper's per-stripe features of a semantic label image (definitions: module docstring).

    Parameters
    ----------
    labels
        (H, W) uint8: 0 background, 1 branch, 2 foliage.
    stripe_height
        Stripe height in pixels of the image: ``n = round(H / stripe_height)`` stripes (16 px,
        as the authors did on 256 px impostors). The stripes split the object's bounding-box
        height, so each covers ``1/n`` of the object in every image.
    n_stripes
        Number of stripes; overrides ``stripe_height`` (the paper: 20-30).
    trunk_ratio
        A stripe is trunk when ``B_i > trunk_ratio * L_i``.
    """
    labels = check_labels(labels)
    big_h, big_w = labels.shape
    n = _n_stripes(big_h, stripe_height, n_stripes)
    occupied = labels != 0
    rows = np.flatnonzero(occupied.any(axis=1))
    if rows.size == 0:
        raise UserError("empty label image: no branch or foliage pixels")
    cols = np.flatnonzero(occupied.any(axis=0))
    top, bottom, left, right = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    h = bottom - top
    crop = labels[top:bottom]

    # per-stripe column counts of branch and foliage pixels, (n, W) each, from row prefix sums;
    # stripe k holds rows [ceil(k h / n), ceil((k + 1) h / n)) of the crop (empty when h < n)
    bounds = -((-np.arange(n + 1) * h) // n)
    prefix = np.zeros((h + 1, 2 * big_w), np.int32)
    prefix[1:, :big_w] = crop == BRANCH
    prefix[1:, big_w:] = crop == FOLIAGE
    np.cumsum(prefix, axis=0, out=prefix)
    counts = prefix[bounds[1:]] - prefix[bounds[:-1]]
    branch_cols, leaf_cols = counts[:, :big_w], counts[:, big_w:]
    rows_per = np.diff(bounds).astype(np.float64)

    occ = (branch_cols + leaf_cols) > 0
    dense = leaf_cols > DENSE_SHARE * rows_per[:, None]
    nonempty = occ.any(axis=1)
    has_dense = dense.any(axis=1)
    a = np.argmax(occ, axis=1).astype(np.float64)
    d = (big_w - np.argmax(occ[:, ::-1], axis=1)).astype(np.float64)
    mid = 0.5 * (a + d)
    b = np.where(has_dense, np.argmax(dense, axis=1), mid)
    c = np.where(has_dense, big_w - np.argmax(dense[:, ::-1], axis=1), mid)

    # root: centre of the branch pixels (else of all object pixels) in the lowest rows
    band = crop[h - max(1, math.ceil(ROOT_BAND * h)):]
    weights = (band == BRANCH).sum(axis=0)
    if weights.sum() == 0:
        weights = (band != 0).sum(axis=0)
    root_x = float(weights @ (np.arange(big_w) + 0.5) / weights.sum())

    box = rows_per * (d - a)
    safe_box = np.where(nonempty, box, 1.0)
    branch_share = np.where(nonempty, branch_cols.sum(axis=1) / safe_box, 0.0)
    leaf_share = np.where(nonempty, leaf_cols.sum(axis=1) / safe_box, 0.0)
    trunk = nonempty & (branch_share > trunk_ratio * leaf_share)

    def norm(x: np.ndarray) -> np.ndarray:
        return np.where(nonempty, (x - root_x) / h, 0.0)

    area = float(h * (right - left))
    return StripeFeatures(
        a=norm(a), b=norm(b), c=norm(c), d=norm(d), branch_share=branch_share, leaf_share=leaf_share,
        trunk=trunk, empty=~nonempty, shape=(big_h, big_w), bbox=(top, bottom, left, right), root_x=root_x,
        branch_density=float(branch_cols.sum()) / area, leaf_density=float(leaf_cols.sum()) / area,
    )


def _overlap(lo1: np.ndarray, hi1: np.ndarray, lo2: np.ndarray, hi2: np.ndarray) -> np.ndarray:
    return np.clip(np.minimum(hi1, hi2) - np.maximum(lo1, lo2), 0.0, None)


def tree_similarity(ref: StripeFeatures, cand: StripeFeatures, *, dense_weight: float = 2.0,
                    trunk_weight: float = 0.3) -> float:
    """``TSim`` in [0, 1] (1 = identical) of two images' stripe features (formula: module docstring).

    Parameters
    ----------
    ref, cand
        Features from :func:`stripe_features` of two images of the same size, same stripe count.
    dense_weight
        Extra weight ``w`` of the dense crown interval against the crown interval.
    trunk_weight
        Weight ``tau`` of the trunk stripes' score against the crown stripes' score.
    """
    if ref.shape != cand.shape:
        raise UserError(f"label images differ in size: {ref.shape[1]}x{ref.shape[0]} vs "
                        f"{cand.shape[1]}x{cand.shape[0]}")
    if ref.n_stripes != cand.n_stripes:
        raise UserError(f"stripe counts differ: {ref.n_stripes} vs {cand.n_stripes}")
    crown_i = _overlap(ref.a, ref.d, cand.a, cand.d)
    crown_u = (ref.d - ref.a) + (cand.d - cand.a) - crown_i
    dense_i = _overlap(ref.b, ref.c, cand.b, cand.c)
    dense_u = (ref.c - ref.b) + (cand.c - cand.b) - dense_i
    agree = 1.0 - np.abs(_branch_fraction(ref) - _branch_fraction(cand))
    score = (crown_i + dense_weight * dense_i) * agree
    mass = crown_u + dense_weight * dense_u
    trunk = ref.trunk | cand.trunk
    crown = ~trunk & (mass > 0)
    parts, weights = [], []
    for group, weight in ((crown, 1.0 - trunk_weight), (trunk, trunk_weight)):
        total = mass[group].sum()
        if total > 0:
            parts.append(score[group].sum() / total)
            weights.append(weight)
    if not parts:  # only when both images are degenerate (zero-width stripes cannot happen otherwise)
        return 0.0
    return float(np.clip(np.dot(parts, weights) / sum(weights), 0.0, 1.0))


def _branch_fraction(f: StripeFeatures) -> np.ndarray:
    """``B / (B + L)``: a bounded stand-in for the paper's ``B/L`` (0 for empty stripes)."""
    total = f.branch_share + f.leaf_share
    return np.where(total > 0, f.branch_share / np.where(total > 0, total, 1.0), 0.0)


@dataclass(frozen=True, eq=False)
class TreeStats:
    """A tree's label image and its optional non-image characteristics, for :func:`tree_loss`."""

    labels: np.ndarray
    """(H, W) uint8 semantic labels: 0 background, 1 branch, 2 foliage."""
    graph_vertices: int | None = None
    """Number of vertices of the branch graph (the paper recommends this regulariser)."""
    leaf_size: float | None = None
    """Average leaf size, in any unit shared by reference and candidate."""
    _features: dict = field(default_factory=dict, init=False, repr=False)

    def features(self, stripe_height: int | None = 16, n_stripes: int | None = None) -> StripeFeatures:
        """:func:`stripe_features` of ``labels``, computed once per stripe setting."""
        key = (stripe_height, n_stripes)
        if key not in self._features:
            self._features[key] = stripe_features(self.labels, stripe_height, n_stripes)
        return self._features[key]


def _ratio(name: str, x, y) -> float:
    """``min(x, y) / max(x, y)`` for non-negative characteristics (1 when both are 0)."""
    if x is None or y is None:
        raise UserError(f"regulariser {name!r} needs {name} for both reference and candidate")
    x, y = float(x), float(y)
    if not (math.isfinite(x) and math.isfinite(y)) or x < 0 or y < 0:
        raise UserError(f"regulariser {name!r}: values must be finite and >= 0, got {x} and {y}")
    hi = max(x, y)
    return 1.0 if hi == 0 else min(x, y) / hi


def _which(regularisers) -> list[str]:
    if regularisers is None:
        return []
    if isinstance(regularisers, str):
        regularisers = [regularisers]
    if isinstance(regularisers, Mapping):
        names = [k for k, on in regularisers.items() if on]
    elif isinstance(regularisers, Iterable):
        names = list(regularisers)
    else:
        raise UserError("regularisers: expected names or a name -> bool mapping")
    unknown = sorted(set(names) - set(REGULARISERS))
    if unknown:
        raise UserError(f"unknown regulariser(s) {', '.join(unknown)} (known: {', '.join(REGULARISERS)})")
    return names


def regularisation_multipliers(ref: TreeStats, cand: TreeStats, regularisers=None, *,
                               stripe_height: int | None = 16, n_stripes: int | None = None) -> dict[str, float]:
    """The paper's multipliers ``min(c, c_ref) / max(c, c_ref)`` by name, for the chosen characteristics.

    ``regularisers``: names from :data:`REGULARISERS` (or a name -> bool mapping); ``height`` and
    ``width`` are the pixel sizes of the label images' object bounding boxes, ``branch_density``
    and ``leaf_density`` the branch and foliage pixel shares of those boxes, ``graph_vertices``
    and ``leaf_size`` come from :class:`TreeStats`.
    """
    names = _which(regularisers)
    out = {}
    if not names:
        return out
    fr, fc = ref.features(stripe_height, n_stripes), cand.features(stripe_height, n_stripes)
    for name in names:
        if name in ("graph_vertices", "leaf_size"):
            out[name] = _ratio(name, getattr(ref, name), getattr(cand, name))
        else:
            out[name] = _ratio(name, getattr(fr, name), getattr(fc, name))
    return out


def _stats(x, what: str) -> TreeStats:
    if isinstance(x, TreeStats):
        return x
    return TreeStats(check_labels(x, what))


def loss_terms(ref, cand, regularisers=None, *, stripe_height: int | None = 16, n_stripes: int | None = None,
               dense_weight: float = 2.0, trunk_weight: float = 0.3) -> dict[str, float]:
    """``tsim``, each multiplier by name, and ``loss`` (as :func:`tree_loss`), for traces."""
    ref, cand = _stats(ref, "reference labels"), _stats(cand, "candidate labels")
    fr, fc = ref.features(stripe_height, n_stripes), cand.features(stripe_height, n_stripes)
    tsim = tree_similarity(fr, fc, dense_weight=dense_weight, trunk_weight=trunk_weight)
    mult = regularisation_multipliers(ref, cand, regularisers, stripe_height=stripe_height, n_stripes=n_stripes)
    return {"tsim": tsim, **mult, "loss": 1.0 - tsim * math.prod(mult.values())}


@LOSSES.register("tree_similarity")
def tree_loss(ref, cand, regularisers=None, *, stripe_height: int | None = 16, n_stripes: int | None = None,
              dense_weight: float = 2.0, trunk_weight: float = 0.3) -> float:
    """``1 - TSim * prod(multipliers)``: the paper's tree loss as a value in [0, 1] to minimise.

    Parameters
    ----------
    ref, cand
        :class:`TreeStats` or (H, W) uint8 label images of the same size. Passing the reference
        as one ``TreeStats`` for a whole search computes its features once.
    regularisers
        Which multipliers to apply: names from :data:`REGULARISERS` or a name -> bool mapping;
        none by default (the paper recommends ``graph_vertices``).
    stripe_height, n_stripes, dense_weight, trunk_weight
        As in :func:`stripe_features` and :func:`tree_similarity`.
    """
    return loss_terms(ref, cand, regularisers, stripe_height=stripe_height, n_stripes=n_stripes,
                      dense_weight=dense_weight, trunk_weight=trunk_weight)["loss"]
