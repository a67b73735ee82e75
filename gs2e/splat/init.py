"""Initial Gaussians from SfM points."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from gs2e.common.errors import InputError

SH_C0 = 0.28209479177387814  # Y_0^0


def rgb_to_sh_dc(rgb01: np.ndarray) -> np.ndarray:
    """Colour in [0,1] -> degree-0 SH coefficient (colour = SH_C0 * c + 0.5)."""
    return (np.asarray(rgb01, np.float64) - 0.5) / SH_C0


def knn_log_scales(xyz: np.ndarray, k: int = 3, min_dist: float = 1e-7) -> np.ndarray:
    """Isotropic log-scale per point: log of the RMS distance to its k nearest
    neighbours (3DGS initialisation), computed with a KD-tree in O(N log N).

    xyz: (N, 3) with N >= 2. Returns (N, 3) float64 (same value on each axis).
    Coincident points get ``min_dist`` instead of log(0).
    """
    xyz = np.asarray(xyz, np.float64)
    n = len(xyz)
    if n < 2:
        raise InputError(f"need at least 2 points to initialise Gaussians, got {n}")
    kk = min(k, n - 1)
    d, _ = cKDTree(xyz).query(xyz, k=kk + 1)  # first neighbour is the point itself
    mean_sq = np.mean(d[:, 1:] ** 2, axis=1)
    s = np.sqrt(np.maximum(mean_sq, min_dist ** 2))
    return np.repeat(np.log(s)[:, None], 3, axis=1)


def init_from_points(xyz: np.ndarray, rgb_u8: np.ndarray, sh_degree: int = 3,
                     init_opacity: float = 0.1, min_points: int = 2) -> dict[str, np.ndarray]:
    """Gaussian parameters from a coloured point cloud (float64 arrays):
    means, quats (identity), log_scales (kNN), opacity_logits (logit of
    ``init_opacity``), sh (N, (d+1)^2, 3) with only the DC term set."""
    xyz = np.asarray(xyz, np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise InputError(f"points must be (N, 3), got {xyz.shape}")
    finite = np.all(np.isfinite(xyz), axis=1)
    xyz, rgb_u8 = xyz[finite], np.asarray(rgb_u8)[finite]
    if len(xyz) < min_points:
        raise InputError(f"too few points to initialise Gaussians: {len(xyz)} < {min_points}")
    n = len(xyz)
    sh = np.zeros((n, (sh_degree + 1) ** 2, 3))
    sh[:, 0, :] = rgb_to_sh_dc(rgb_u8 / 255.0)
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    p = float(init_opacity)
    return {"means": xyz.copy(), "quats": quats, "log_scales": knn_log_scales(xyz),
            "opacity_logits": np.full(n, np.log(p / (1 - p))), "sh": sh}
