"""Rotations: quaternions (w, x, y, z; Hamilton; unit), matrices, geodesic angles.

All functions are vectorised over leading axes: ``q`` has shape (..., 4) and
``R`` has shape (..., 3, 3). Angles are radians.
"""

from __future__ import annotations

import numpy as np


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4); raises ValueError on zero or non-finite input."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    if not np.all(np.isfinite(n)) or np.any(n == 0):
        raise ValueError("quaternion with zero or non-finite norm")
    return q / n


def quat_to_rotmat(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (w, x, y, z) -> (..., 3, 3) rotation matrices."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    R = np.empty(w.shape + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def rotmat_to_quat(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions with w >= 0.

    Uses the largest-diagonal branch (Shepperd) so it is stable near 180 deg.
    """
    R = np.asarray(R, dtype=np.float64)
    shp = R.shape[:-2]
    M = R.reshape(-1, 3, 3)
    tr = np.trace(M, axis1=1, axis2=2)
    diag = np.stack([M[:, 0, 0], M[:, 1, 1], M[:, 2, 2]], axis=1)
    choice = np.argmax(np.concatenate([tr[:, None], diag], axis=1), axis=1)
    q = np.empty((M.shape[0], 4))
    for c in range(4):
        idx = choice == c
        if not np.any(idx):
            continue
        m = M[idx]
        if c == 0:
            s = np.sqrt(1.0 + tr[idx]) * 2
            q[idx] = np.stack([0.25 * s, (m[:, 2, 1] - m[:, 1, 2]) / s,
                               (m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 1, 0] - m[:, 0, 1]) / s], 1)
        elif c == 1:
            s = np.sqrt(1.0 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2]) * 2
            q[idx] = np.stack([(m[:, 2, 1] - m[:, 1, 2]) / s, 0.25 * s,
                               (m[:, 0, 1] + m[:, 1, 0]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s], 1)
        elif c == 2:
            s = np.sqrt(1.0 + m[:, 1, 1] - m[:, 0, 0] - m[:, 2, 2]) * 2
            q[idx] = np.stack([(m[:, 0, 2] - m[:, 2, 0]) / s, (m[:, 0, 1] + m[:, 1, 0]) / s,
                               0.25 * s, (m[:, 1, 2] + m[:, 2, 1]) / s], 1)
        else:
            s = np.sqrt(1.0 + m[:, 2, 2] - m[:, 0, 0] - m[:, 1, 1]) * 2
            q[idx] = np.stack([(m[:, 1, 0] - m[:, 0, 1]) / s, (m[:, 0, 2] + m[:, 2, 0]) / s,
                               (m[:, 1, 2] + m[:, 2, 1]) / s, 0.25 * s], 1)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    q[q[:, 0] < 0] *= -1
    return q.reshape(shp + (4,))


def geodesic_angle(R_a: np.ndarray, R_b: np.ndarray) -> np.ndarray:
    """Angle (rad, in [0, pi]) of R_b R_a^T, stable near 0 and pi.

    Uses atan2(|skew part|, trace part) instead of arccos((tr-1)/2), which
    loses half the digits near 0 and pi.
    """
    D = np.asarray(R_b) @ np.swapaxes(np.asarray(R_a), -1, -2)
    s = np.stack([D[..., 2, 1] - D[..., 1, 2], D[..., 0, 2] - D[..., 2, 0],
                  D[..., 1, 0] - D[..., 0, 1]], axis=-1)
    sin_term = 0.5 * np.linalg.norm(s, axis=-1)
    cos_term = 0.5 * (np.trace(D, axis1=-2, axis2=-1) - 1.0)
    ang = np.arctan2(sin_term, cos_term)
    # Near pi the skew part vanishes faster than the angle: refine from the
    # symmetric part through the quaternion of D (w = cos(angle/2)).
    q = rotmat_to_quat(D)
    ang_q = 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))
    return np.where(cos_term < 0, ang_q, ang)


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True):
    """Similarity (s, R, t) minimising sum ||s R src_i + t - dst_i||^2.

    src, dst: (N, 3) with N >= 3 non-collinear points. Returns (s, R (3,3), t (3,)).
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3 or src.shape[0] < 3:
        raise ValueError(f"umeyama needs matching (N>=3, 3) arrays, got {src.shape} and {dst.shape}")
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    cov = xd.T @ xs / len(src)
    U, S, Vt = np.linalg.svd(cov)
    d = np.ones(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        d[-1] = -1
    R = U @ np.diag(d) @ Vt
    var_s = (xs ** 2).sum() / len(src)
    s = float((S * d).sum() / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t
