"""Image motion of the scene between two camera poses."""

from __future__ import annotations

import numpy as np


def pixel_motion_px(points_w: np.ndarray, c2w_a: np.ndarray, c2w_b: np.ndarray, K: np.ndarray,
                    width: int, height: int, percentile=99.0, near: float = 1e-3):
    """Displacement (px) of scene points between two views: the ``percentile``
    of |x_b - x_a| over points in front of both cameras and inside view a.

    points_w : (P, 3) world points (e.g. Gaussian centres); c2w_a, c2w_b : (4, 4);
    K : (3, 3); percentile : a number (a float back) or a sequence (an array of
    as many back). 0.0 if no point is visible.
    """
    pts = np.asarray(points_w, np.float64)

    def project(c2w):
        R, t = c2w[:3, :3], c2w[:3, 3]
        pc = (pts - t) @ R  # world -> camera: R^T (p - t)
        z = pc[:, 2]
        uv = (pc[:, :2] / np.maximum(z, near)[:, None]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
        return uv, z

    uv_a, z_a = project(np.asarray(c2w_a, np.float64))
    uv_b, z_b = project(np.asarray(c2w_b, np.float64))
    ok = (z_a > near) & (z_b > near) & (uv_a[:, 0] >= 0) & (uv_a[:, 0] < width) & \
         (uv_a[:, 1] >= 0) & (uv_a[:, 1] < height)
    if np.ndim(percentile):
        if not ok.any():
            return np.zeros(len(percentile))
        return np.percentile(np.linalg.norm(uv_b[ok] - uv_a[ok], axis=1), percentile)
    if not ok.any():
        return 0.0
    return float(np.percentile(np.linalg.norm(uv_b[ok] - uv_a[ok], axis=1), percentile))
