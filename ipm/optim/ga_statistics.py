"""Gene statistics of the paper's GA, and genes in the unit cube.

The statistics (:class:`GeneStatistics`, :func:`collect_statistics`) are gathered once per
generator on random samples ``x`` (a cached pipeline stage)::

    V(k)   = mean | f(x + h e_k) - f(x) | / h                 (average rate of change of gene k)
    P_ij   = P( x is good | (j-1)/B < x_i < j/B )               (paper: P(F(x) > eps | ...))
    P_0    = P( x is good )
    Q_ij   = sign(P_ij - P_0) * max(P_ij, P_0) / min(P_ij, P_0)
    Q(G)   = sum_i Q(i, floor(G_i * B))

"Good" is the paper's ``F(x) > eps`` for a similarity; for a loss it is ``loss <= eps_f`` with
``eps_f`` the ``good_fraction`` quantile of that objective's sample losses, one threshold per
member ``f`` of the family ``F`` (losses of different targets need not share a scale).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Callable

import numpy as np

from ipm.errors import UserError
from ipm.settings import Range, Settings, at_least

if TYPE_CHECKING:
    from ipm.generators.base import ParamSpec


def _levels(spec: ParamSpec) -> tuple[np.ndarray, np.ndarray]:
    """Lowest integer and number of integer values of each discrete gene (1 for continuous)."""
    lo = np.where(spec.discrete, np.ceil(spec.lower - 1e-9), 0.0)
    n = np.where(spec.discrete, np.floor(spec.upper + 1e-9) - lo + 1, 1.0)
    return lo, np.maximum(n, 1).astype(np.int64)


def snap(spec: ParamSpec, u: np.ndarray) -> np.ndarray:
    """Unit vectors ``u`` (..., N) with discrete genes moved onto their grid (what ``from_unit`` makes)."""
    u = np.clip(np.asarray(u, np.float64), 0.0, 1.0)
    grid = np.clip(spec.to_unit(spec.from_unit(u)), 0.0, 1.0)
    return np.where(spec.discrete, grid, u)


def random_genes(spec: ParamSpec, rng: np.random.Generator, n: int) -> np.ndarray:
    """``n`` uniform random unit vectors; discrete genes uniform over their integer values."""
    lo, levels = _levels(spec)
    u = rng.random((n, len(spec)))
    k = np.floor(u * levels)  # a uniform level index per discrete gene
    span = np.where(spec.discrete, spec.upper - spec.lower, 1.0)
    disc = np.clip((lo + k - spec.lower) / np.where(span > 0, span, 1.0), 0.0, 1.0)
    return np.where(spec.discrete, disc, u)


@dataclass(frozen=True)
class _Scalars(Settings):
    """The scalar fields of a statistics file, checked as settings are (the arrays: ``from_dict``)."""

    KIND = "field"

    n_samples: Annotated[int, at_least(1)]
    h: Annotated[float, Range(0.0, 1.0, open_lo=True, open_hi=True)]
    good_fraction: Annotated[float, Range(0.0, 1.0, open_lo=True)]
    prior: Annotated[float, at_least(0.0)]


@dataclass(frozen=True)
class GeneStatistics:
    """Per-gene statistics of a generator's losses on random samples (the paper's V, P, Q)."""

    names: tuple[str, ...]
    """Gene names, in vector order (must match the spec they are used with)."""
    counts: np.ndarray
    """Samples whose gene ``i`` fell in bin ``j``, shape (N, B) (summed over the family)."""
    good: np.ndarray
    """Good samples among them, shape (N, B)."""
    v: np.ndarray
    """``V(k)``: mean absolute rate of change of the loss along gene ``k`` (unit cube), shape (N,)."""
    epsilon: np.ndarray
    """Loss threshold of "good" per objective of the family, shape (F,)."""
    n_samples: int
    """Random points drawn (each evaluated at ``x`` and ``x + h e_k``)."""
    h: float
    """Finite-difference step used for ``V``."""
    good_fraction: float
    """Quantile of each objective's losses used as its ``epsilon``."""
    prior: float
    """Pseudo-samples at ``P_0`` added to each bin."""

    FORMAT = "ipm-ga-statistics"
    VERSION = 1

    @property
    def bins(self) -> int:
        return self.counts.shape[1]

    @property
    def p0(self) -> float:
        """``P_0 = P(good)`` over all samples (each gene's bins count every sample once)."""
        total = self.counts[0].sum()
        return float(self.good[0].sum() / total) if total else 0.0

    @property
    def p(self) -> np.ndarray:
        """``P_ij = P(good | x_i in bin j)``, shape (N, B), shrunk towards ``P_0`` by ``prior``."""
        return (self.good + self.prior * self.p0) / np.maximum(self.counts + self.prior, 1e-12)

    @property
    def q(self) -> np.ndarray:
        """``Q_ij = sign(P_ij - P_0) * max(P_ij, P_0) / min(P_ij, P_0)``, shape (N, B)."""
        p, p0 = self.p, self.p0
        if p0 <= 0.0:
            return np.zeros_like(p)
        ratio = np.maximum(p, p0) / np.maximum(np.minimum(p, p0), 1e-12)
        return np.sign(p - p0) * ratio

    def quality(self, genomes: np.ndarray) -> np.ndarray:
        """``Q(G) = sum_i Q(i, floor(G_i * B))`` for genomes (..., N) in the unit cube."""
        g = np.asarray(genomes, np.float64)
        j = np.clip(np.floor(g * self.bins), 0, self.bins - 1).astype(np.int64)
        q = self.q
        return q[np.arange(q.shape[0]), j].sum(axis=-1)

    def mutation_weights(self) -> np.ndarray:
        """Probabilities of the genes to be mutated: proportional to ``V(k)``, plus 1 % of the
        mean so that a gene whose samples never moved the loss can still change."""
        w = self.v + 0.01 * max(float(self.v.mean()), 1e-12)
        return w / w.sum()

    def check(self, spec: ParamSpec) -> None:
        """``UserError`` unless these statistics were collected for ``spec``'s genes."""
        if tuple(spec.names) != self.names:
            raise UserError(f"GA statistics are for genes {list(self.names)[:4]}... ({len(self.names)}), "
                            f"not for this generator's {list(spec.names)[:4]}... ({len(spec.names)})")

    def to_dict(self) -> dict:
        return {"format": self.FORMAT, "version": self.VERSION, "names": list(self.names),
                "counts": self.counts.tolist(), "good": self.good.tolist(), "v": self.v.tolist(),
                "epsilon": self.epsilon.tolist(), "n_samples": self.n_samples, "h": self.h,
                "good_fraction": self.good_fraction, "prior": self.prior}

    def save(self, path: str | Path) -> None:
        """Write as JSON, atomically."""
        from ipm.io.atomic import atomic_path

        with atomic_path(path) as tmp:
            tmp.write_text(json.dumps(self.to_dict()) + "\n")

    @classmethod
    def from_dict(cls, d: dict, source: str = "GA statistics") -> GeneStatistics:
        """Validate and build; ``UserError`` naming the problem otherwise."""

        def bad(why: str) -> UserError:
            return UserError(f"{source}: {why}")

        if not isinstance(d, dict) or d.get("format") != cls.FORMAT:
            raise bad(f"not an {cls.FORMAT} file")
        if d.get("version") != cls.VERSION:
            raise bad(f"unsupported version {d.get('version')!r} (expected {cls.VERSION})")
        missing = [k for k in ("names", "counts", "good", "v", "epsilon", "n_samples", "h", "good_fraction",
                               "prior") if k not in d]
        if missing:
            raise bad(f"missing {', '.join(missing)}")
        names = d["names"]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise bad("names must be a non-empty list of strings")
        try:
            counts = np.asarray(d["counts"], np.float64)
            good = np.asarray(d["good"], np.float64)
            v = np.asarray(d["v"], np.float64)
            eps = np.asarray(d["epsilon"], np.float64)
        except (TypeError, ValueError) as e:
            raise bad(f"malformed numbers ({e})") from None
        try:
            scalars = _Scalars(**{k: d[k] for k in _Scalars.names()})
        except UserError as e:
            raise bad(str(e)) from None
        n_samples, h, frac, prior = scalars.n_samples, float(scalars.h), float(scalars.good_fraction), \
            float(scalars.prior)
        n = len(names)
        if counts.ndim != 2 or counts.shape[0] != n or counts.shape[1] < 1 or good.shape != counts.shape:
            raise bad(f"counts and good must both have shape ({n}, B), got {counts.shape} and {good.shape}")
        if v.shape != (n,):
            raise bad(f"v must have shape ({n},), got {v.shape}")
        if eps.ndim != 1:
            raise bad("epsilon must be a list")
        arrays = {"counts": counts, "good": good, "v": v, "epsilon": eps}
        for key, arr in arrays.items():
            if not np.all(np.isfinite(arr)):
                raise bad(f"{key} has non-finite values")
        if np.any(counts < 0) or np.any(good < 0) or np.any(good > counts) or np.any(v < 0):
            raise bad("counts, good and v must be >= 0, with good <= counts")
        if np.any(counts != np.round(counts)) or np.any(good != np.round(good)):
            raise bad("counts and good must be integers")
        if not np.all(counts.sum(axis=1) == counts[0].sum()) or not np.all(good.sum(axis=1) == good[0].sum()):
            raise bad("every gene's bins must count the same samples")
        return cls(tuple(names), counts.astype(np.int64), good.astype(np.int64), v, eps, n_samples, h, frac, prior)

    @classmethod
    def load(cls, path: str | Path) -> GeneStatistics:
        """Read a file written by :meth:`save`; ``UserError`` if it is missing or malformed."""
        path = Path(path)
        try:
            d = json.loads(path.read_text())
        except FileNotFoundError:
            raise UserError(f"GA statistics file not found: {path}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise UserError(f"GA statistics file {path} is not valid JSON ({e})") from None
        return cls.from_dict(d, source=f"GA statistics file {path}")


def collect_statistics(spec: ParamSpec, evaluate: Callable[[np.ndarray], float | np.ndarray], n_samples: int,
                       bins: int, seed: int = 0, progress: bool = False, h: float = 0.05,
                       good_fraction: float = 0.1, prior: float = 2.0) -> GeneStatistics:
    """The paper's statistics from ``n_samples`` random points of the unit cube.

    ``evaluate(u) -> loss`` maps a unit vector (N,) to the loss of that sample; to gather the
    statistics over a *family* of objectives (the paper's ``F``: one per reference image), it
    returns a vector of losses (F,), one per objective. Non-finite losses count as bad and are
    left out of ``V``.

    Each point ``x`` is evaluated twice: at ``x`` and at ``x + h e_k`` for one gene ``k`` (the
    genes taken in turn, so each gets ``n_samples / N`` differences); the step goes down where
    up would leave the cube, and a discrete gene moves by ``max(h, one level)`` rounded to its
    grid. ``V(k)`` is the mean of ``|f(x + h e_k) - f(x)| / step`` over its differences and the
    family. Both points enter ``P_ij`` (the second differs from a uniform sample only in gene
    ``k`` near the cube's faces). Costs ``2 n_samples`` evaluations.
    """
    from tqdm import tqdm

    if n_samples < 1 or bins < 1:
        raise UserError(f"statistics need n_samples >= 1 and bins >= 1, got {n_samples} and {bins}")
    rng = np.random.default_rng(seed)
    n = len(spec)
    span = np.where(spec.discrete, spec.upper - spec.lower, 1.0)
    level = np.where(spec.discrete & (span > 0), 1.0 / np.where(span > 0, span, 1.0), 0.0)
    points = random_genes(spec, rng, n_samples)
    order = np.concatenate([rng.permutation(n) for _ in range(-(-n_samples // n))])[:n_samples]
    all_u, all_loss = [], []
    diffs = [[] for _ in range(n)]
    n_obj = None
    for s in tqdm(range(n_samples), desc="GA statistics", unit="sample", disable=not progress, leave=False):
        x, k = points[s], order[s]
        step = max(h, level[k])
        if spec.discrete[k] and level[k] > 0:
            step = max(round(step / level[k]), 1) * level[k]
        x2 = x.copy()
        x2[k] = x[k] + step if x[k] + step <= 1.0 + 1e-12 else x[k] - step
        x2 = snap(spec, x2)
        moved = abs(x2[k] - x[k])
        pair = []
        for u in (x, x2):
            loss = np.atleast_1d(np.asarray(evaluate(u.copy()), np.float64)).ravel()
            if n_obj is None:
                n_obj = len(loss)
            if len(loss) != n_obj or n_obj == 0:
                raise ValueError(f"evaluate returned {len(loss)} losses, expected {n_obj}")
            pair.append(loss)
            all_u.append(u)
            all_loss.append(loss)
        if moved > 0:
            d = np.abs(pair[1] - pair[0]) / moved
            diffs[k].extend(d[np.isfinite(d)].tolist())
    u = np.array(all_u)
    losses = np.array(all_loss)  # (2 n_samples, F)
    finite = np.isfinite(losses)
    eps = np.array([np.quantile(losses[finite[:, f], f], good_fraction) if finite[:, f].any() else -np.inf
                    for f in range(n_obj)])
    good = (finite & (losses <= eps[None, :])).sum(axis=1)  # good objectives per sample
    j = np.clip(np.floor(u * bins), 0, bins - 1).astype(np.int64)  # (S, N)
    counts = np.zeros((n, bins), np.int64)
    good_counts = np.zeros((n, bins), np.int64)
    for i in range(n):
        counts[i] = np.bincount(j[:, i], minlength=bins) * n_obj
        good_counts[i] = np.bincount(j[:, i], weights=good, minlength=bins).astype(np.int64)
    v = np.array([np.mean(dk) if dk else 0.0 for dk in diffs])
    return GeneStatistics(tuple(spec.names), counts, good_counts, v, eps, int(n_samples), float(h),
                          float(good_fraction), float(prior))
