"""Image motion of the scene between two camera poses."""

from __future__ import annotations

import numpy as np


def project_points(points_w: np.ndarray, c2w: np.ndarray, K: np.ndarray,
                   near: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole projection of world points: (uv (P, 2) px, z (P,) camera depth).

    points_w : (P, 3); c2w : (4, 4) camera-to-world (OpenCV axes); K : (3, 3).
    Points at z <= ``near`` get uv as if at ``near`` (mask them with z)."""
    pts = np.asarray(points_w, np.float64)
    c2w = np.asarray(c2w, np.float64)
    pc = (pts - c2w[:3, 3]) @ c2w[:3, :3]  # world -> camera: R^T (p - t)
    z = pc[:, 2]
    uv = (pc[:, :2] / np.maximum(z, near)[:, None]) * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return uv, z


def pixel_motion_px(points_w: np.ndarray, c2w_a: np.ndarray, c2w_b: np.ndarray, K: np.ndarray,
                    width: int, height: int, percentile=99.0, near: float = 1e-3):
    """Displacement (px) of scene points between two views: the ``percentile``
    of |x_b - x_a| over points in front of both cameras and inside view a.

    points_w : (P, 3) world points (e.g. Gaussian centres); c2w_a, c2w_b : (4, 4);
    K : (3, 3); percentile : a number (a float back) or a sequence (an array of
    as many back). 0.0 if no point is visible.
    """
    uv_a, z_a = project_points(points_w, c2w_a, K, near)
    uv_b, z_b = project_points(points_w, c2w_b, K, near)
    ok = (z_a > near) & (z_b > near) & (uv_a[:, 0] >= 0) & (uv_a[:, 0] < width) & \
         (uv_a[:, 1] >= 0) & (uv_a[:, 1] < height)
    if np.ndim(percentile):
        if not ok.any():
            return np.zeros(len(percentile))
        return np.percentile(np.linalg.norm(uv_b[ok] - uv_a[ok], axis=1), percentile)
    if not ok.any():
        return 0.0
    return float(np.percentile(np.linalg.norm(uv_b[ok] - uv_a[ok], axis=1), percentile))
