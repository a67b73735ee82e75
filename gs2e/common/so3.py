"""Rotations: quaternions (w, x, y, z; Hamilton; unit), matrices, geodesic angles.

All functions are vectorised over leading axes: ``q`` has shape (..., 4) and
``R`` has shape (..., 3, 3). Angles are radians.

Quaternion algebra (product, exp, log, angle) goes through
``scipy.spatial.transform.Rotation``, which is as exact as a hand-written
version (checked against 50-digit mpmath, near 0 and pi). Hand-written and kept:

- ``quat_to_rotmat`` / ``rotmat_to_quat``: scipy's are as exact (max error
  4e-16 vs 7e-16, 1.5e-16 vs 2e-16) but round differently, and these two set the
  bytes of every trajectory (``trajectory.curve`` splits and joins poses with
  them); switching would change published outputs, not their accuracy.
- ``geodesic_angle``: 5x more exact than scipy's ``(Rb * Ra.inv()).magnitude()``
  (max abs error 3e-17 vs 1.7e-16 at 1e-12 rad, 2e-16 vs 7e-16 near pi).
- ``quat_mean``: scipy's ``Rotation.mean`` is another estimator (eigenvector of
  the weighted outer products), not this sign-aligned chordal mean.
- ``umeyama``: scipy has no similarity (scale) fit; ``align_vectors`` is the
  rotation alone.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


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


# ---------------------------------------------------------------- quaternion algebra
# (..., 4) arrays in (w, x, y, z) order; scipy's Rotation holds one flat batch.

def _rotations(q: np.ndarray) -> tuple[Rotation, tuple[int, ...]]:
    """Rotation batch of (..., 4) wxyz quaternions (normalised) and the batch shape."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True), q.shape[:-1]


def _quats(r: Rotation, shape: tuple[int, ...]) -> np.ndarray:
    return r.as_quat(scalar_first=True).reshape(shape + (4,))


def quat_multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a*b (rotation b first, then a) of unit quaternions,
    broadcasting over (..., 4)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    ra, shape = _rotations(a)
    return _quats(ra * _rotations(b)[0], shape)


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector (..., 3) (axis * angle, angle in [0, pi]) of unit quaternions.

    The sign of ``q`` is irrelevant (q and -q give the same result); stable
    near 0 and pi."""
    r, shape = _rotations(q)
    return r.as_rotvec().reshape(shape + (3,))


def quat_exp(rotvec: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3) (axis * angle, rad).

    ``w = cos(angle / 2)`` (negative beyond pi: continuous in the vector)."""
    r = np.asarray(rotvec, dtype=np.float64)
    return _quats(Rotation.from_rotvec(r.reshape(-1, 3)), r.shape[:-1])


def quat_angle(q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
    """Geodesic angle (rad, [0, pi]) between the rotations of unit quaternions,
    stable near 0 and pi and independent of the signs of ``q_a`` and ``q_b``."""
    a, b = np.broadcast_arrays(np.asarray(q_a, dtype=np.float64), np.asarray(q_b, dtype=np.float64))
    ra, shape = _rotations(a)
    return (ra.inv() * _rotations(b)[0]).magnitude().reshape(shape)


def quat_make_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 of a (N, 4) sequence so that consecutive
    quaternions have a non-negative dot product (no jumps to the antipode).

    The first quaternion keeps its sign. Exactly orthogonal neighbours (a 180 deg
    relative rotation) keep theirs: both choices are equally short.
    """
    q = np.asarray(q, dtype=np.float64)
    if len(q) < 2:
        return q.copy()
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    flips = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
    return q * flips[:, None]


def quat_mean(q: np.ndarray, weights: np.ndarray | None = None, axis: int = -2,
              reference: np.ndarray | None = None) -> np.ndarray:
    """Sign-aligned weighted quaternion average (the chordal L2 mean to 2nd order).

    Each quaternion along ``axis`` is flipped onto the hemisphere of
    ``reference`` (default: the first one), then the weighted sum is normalised.
    ``q``: (..., K, 4) with the default ``axis=-2``. If the aligned sum vanishes
    (rotations spread evenly over 180 deg, no unique mean) the reference is returned.
    """
    q = np.moveaxis(np.asarray(q, dtype=np.float64), axis, -2)
    ref = q[..., :1, :] if reference is None else np.asarray(reference, np.float64)[..., None, :]
    sgn = np.where(np.sum(q * ref, axis=-1, keepdims=True) < 0, -1.0, 1.0)
    w = np.ones(q.shape[:-1] + (1,)) if weights is None else np.asarray(weights, np.float64)[..., None]
    s = np.sum(q * sgn * w, axis=-2)
    n = np.linalg.norm(s, axis=-1, keepdims=True)
    ref0 = ref[..., 0, :]
    ok = n > 1e-12
    return np.where(ok, s / np.where(ok, n, 1.0), ref0 / np.linalg.norm(ref0, axis=-1, keepdims=True))
