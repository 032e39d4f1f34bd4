"""Camera centres and the similarity alignment, in plain NumPy (no COLMAP needed); the frame
conversions are ``ipm.render.cameras.gl_to_colmap`` / ``colmap_to_gl``."""
from __future__ import annotations

import numpy as np

def camera_centre(cam_from_world: np.ndarray) -> np.ndarray:
    """World position of a COLMAP camera, -R^T t."""
    m = np.asarray(cam_from_world, np.float64)
    return -m[:3, :3].T @ m[:3, 3]


def umeyama(src: np.ndarray, dst: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity (scale s, rotation R, translation t) with dst ~ s R src + t
    (Umeyama 1991). ``src`` and ``dst`` are (n, 3) corresponding points, n >= 3, not collinear."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or len(src) < 3:
        raise ValueError(f"umeyama needs two (n >= 3, 3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = (xs ** 2).sum() / len(src)
    if var_s <= 0:
        raise ValueError("umeyama: the source points coincide")
    cov = xd.T @ xs / len(src)
    u, d, vt = np.linalg.svd(cov)
    sign = np.ones(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        sign[2] = -1.0
    r = u @ np.diag(sign) @ vt
    s = float((d * sign).sum() / var_s)
    t = mu_d - s * r @ mu_s
    return s, r, t


def robust_umeyama(src: np.ndarray, dst: np.ndarray, rounds: int = 3, factor: float = 3.0,
                   floor: float = 0.01) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Umeyama, then refit without the correspondences whose residual exceeds both ``factor``
    times the median and ``floor`` times the RMS spread of ``dst`` (a misregistered camera);
    returns (s, R, t, inlier mask)."""
    src, dst = np.asarray(src, np.float64), np.asarray(dst, np.float64)
    keep = np.ones(len(src), bool)
    s, r, t = umeyama(src, dst)
    spread = np.sqrt(((dst - dst.mean(0)) ** 2).sum(1).mean())
    for _ in range(rounds):
        res = np.linalg.norm(apply_similarity(src, s, r, t) - dst, axis=1)
        new = res <= max(factor * np.median(res[keep]), floor * spread)
        if new.sum() < 3 or np.array_equal(new, keep):
            break
        keep = new
        s, r, t = umeyama(src[keep], dst[keep])
    return s, r, t, keep


def apply_similarity(points: np.ndarray, s: float, r: np.ndarray, t: np.ndarray) -> np.ndarray:
    """s R p + t for each row p of ``points``."""
    return s * np.asarray(points, np.float64) @ np.asarray(r).T + np.asarray(t)
