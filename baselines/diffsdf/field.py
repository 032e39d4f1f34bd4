"""The SDF grid outside the differentiable part: sphere initialisation, x2 upsampling and
re-distancing (numpy / scipy)."""
from __future__ import annotations

import numpy as np
from scipy import ndimage


def grid_shape(lo: np.ndarray, hi: np.ndarray, n: int) -> tuple[int, int, int]:
    """Cells per axis: ``n`` along the box's longest side, near-cubic cells elsewhere (>= 4)."""
    ext = hi - lo
    return tuple(int(max(4, round(n * e / ext.max()))) for e in ext)


def cell_centres(lo: np.ndarray, hi: np.ndarray, shape: tuple) -> list[np.ndarray]:
    """Per-axis cell-centre coordinates of a grid of ``shape`` over [lo, hi]."""
    return [lo[k] + (np.arange(shape[k]) + 0.5) * (hi[k] - lo[k]) / shape[k] for k in range(3)]


def sphere(lo: np.ndarray, hi: np.ndarray, shape: tuple, radius: float) -> np.ndarray:
    """SDF (units of the box's longest side L) of a sphere of ``radius`` L at the box centre."""
    scale = float((hi - lo).max())
    c = 0.5 * (lo + hi)
    x, y, z = np.meshgrid(*cell_centres(lo, hi, shape), indexing="ij")
    r = np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) / scale
    return (r - radius).astype(np.float32)


def upsample(field: np.ndarray) -> np.ndarray:
    """Twice the cells per axis, trilinear between the old cell centres (edges clamped)."""
    out = field
    for axis in range(3):
        n = out.shape[axis]
        u = np.clip((np.arange(2 * n) + 0.5) / 2 - 0.5, 0, n - 1)
        i0 = np.minimum(np.floor(u).astype(int), n - 2)
        w = (u - i0).reshape([-1 if k == axis else 1 for k in range(3)])
        out = np.take(out, i0, axis) * (1 - w) + np.take(out, i0 + 1, axis) * w
    return out.astype(np.float32)


def surface_cells(field: np.ndarray) -> np.ndarray:
    """Cells that are a corner of a 2x2x2 block of cell centres with both signs: the values
    that the trilinear zero level set depends on."""
    pos = field > 0
    lo, hi = pos.copy(), pos.copy()  # per block: any positive / all positive
    for axis in range(3):
        a = [slice(None)] * 3
        b = [slice(None)] * 3
        a[axis], b[axis] = slice(0, -1), slice(1, None)
        lo, hi = lo[tuple(a)] | lo[tuple(b)], hi[tuple(a)] & hi[tuple(b)]
    mixed = lo & ~hi
    out = np.zeros_like(pos)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                out[dx:dx + mixed.shape[0], dy:dy + mixed.shape[1], dz:dz + mixed.shape[2]] |= mixed
    return out


def redistance(field: np.ndarray, spacing: np.ndarray) -> np.ndarray:
    """Distance values again away from the surface, the surface itself untouched.

    The cells the trilinear zero level set depends on (``surface_cells``) keep their values;
    every other cell takes the distance to the foot point of its nearest such cell (the cell
    moved along the central-difference normal by ``f / |grad f|``), with its old sign.
    ``spacing`` is the cell size in the field's units.
    """
    f = field.astype(np.float64)
    keep = surface_cells(f)
    if not keep.any():
        return field
    cells = np.nonzero(keep)
    grad = np.empty((len(cells[0]), 3))
    for axis in range(3):  # central differences, one-sided at the grid faces
        up, down = list(cells), list(cells)
        up[axis] = np.minimum(cells[axis] + 1, f.shape[axis] - 1)
        down[axis] = np.maximum(cells[axis] - 1, 0)
        grad[:, axis] = (f[tuple(up)] - f[tuple(down)]) / ((up[axis] - down[axis]) * spacing[axis])
    norm = np.linalg.norm(grad, axis=1)
    foot = np.stack(cells, 1) * spacing - (f[cells] / np.maximum(norm, 1e-3) ** 2)[:, None] * grad
    row = np.zeros(f.shape, np.int32)
    row[cells] = np.arange(len(foot))
    nearest = ndimage.distance_transform_edt(~keep, sampling=spacing, return_distances=False, return_indices=True)
    which = row[tuple(nearest)]
    del nearest
    dist2 = np.zeros(f.shape)
    for axis in range(3):
        coord = (np.arange(f.shape[axis]) * spacing[axis]).reshape([-1 if k == axis else 1 for k in range(3)])
        dist2 += (coord - foot[which, axis]) ** 2
    out = np.sqrt(dist2)
    out = np.where(f > 0, out, -out)
    out[keep] = f[keep]
    return out.astype(np.float32)
