"""Projection of 3D Gaussians to screen-space 2D Gaussians (EWA splatting).

Conventions
-----------
- ``viewmat`` is world-to-camera 4x4 with OpenCV camera axes (x right, y down,
  z forward); pixel centres lie at integer + 0.5 (COLMAP), so the pixel in
  column j, row i is evaluated at (j + 0.5, i + 0.5).
- quaternions are (w, x, y, z), normalised at use; scales are log-scales.
- 2D covariance = J W Sigma W^T J^T + 0.3 px^2 * I (the anti-aliasing low-pass
  of 3DGS); J is the EWA Jacobian of the perspective map at the Gaussian
  centre, with x/z and y/z clamped to 1.3x the field of view (as 3DGS/gsplat
  do) so off-screen Gaussians do not get huge footprints.
- a Gaussian is culled (radius 0) if its centre depth z < near or > far, its
  2D covariance is not positive definite, or its 3-sigma box misses the image.
- radius = ceil(3 * sqrt(largest eigenvalue of the 2D covariance)) px.

All arithmetic is float64 per Gaussian (O(N), cheap) whatever the storage
dtype; ``prange`` over Gaussians, each writes only its own row: deterministic.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit, prange

LOWPASS_PX2 = 0.3
MAX_RADIUS_PX = 1.0e6  # caps the int conversion of absurd radii


@njit(cache=True, fastmath=False)
def _quat_to_rot(qw, qx, qy, qz, R):
    n = math.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    w, x, y, z = qw / n, qx / n, qy / n, qz / n
    R[0, 0] = 1.0 - 2.0 * (y * y + z * z)
    R[0, 1] = 2.0 * (x * y - w * z)
    R[0, 2] = 2.0 * (x * z + w * y)
    R[1, 0] = 2.0 * (x * y + w * z)
    R[1, 1] = 1.0 - 2.0 * (x * x + z * z)
    R[1, 2] = 2.0 * (y * z - w * x)
    R[2, 0] = 2.0 * (x * z - w * y)
    R[2, 1] = 2.0 * (y * z + w * x)
    R[2, 2] = 1.0 - 2.0 * (x * x + y * y)
    return n, w, x, y, z


@njit(inline="always", cache=True, fastmath=False)
def _mul3(A, B, out, a_t, b_t):
    """out = op(A) op(B) for 3x3 arrays, op transposing where the flag is set;
    each entry sums k = 0, 1, 2 in order."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += (A[k, i] if a_t else A[i, k]) * (B[j, k] if b_t else B[k, j])
            out[i, j] = acc


@njit(cache=True, fastmath=False)
def _cov_cam(quat, logscale, V, Rq, M, S3, Sc):
    """Rq (rotation of the Gaussian), M = Rq diag(s), S3 = M M^T, Sc = V S3 V^T."""
    _quat_to_rot(quat[0], quat[1], quat[2], quat[3], Rq)
    for j in range(3):
        s = math.exp(logscale[j])
        for i in range(3):
            M[i, j] = Rq[i, j] * s
    _mul3(M, M, S3, False, True)
    tmp = np.empty((3, 3))
    _mul3(V, S3, tmp, False, False)
    _mul3(tmp, V, Sc, False, True)


@njit(parallel=True, cache=True, fastmath=False)
def cov3d_kernel(quats, logscales, cov6):
    """World-space 3D covariances Rq diag(s)^2 Rq^T, upper triangle per
    Gaussian: cov6 (N,6) = xx, xy, xz, yy, yz, zz (same arithmetic as
    :func:`_cov_cam`, so projecting from them is bit-identical)."""
    for g in prange(quats.shape[0]):
        n = math.sqrt(quats[g, 0] * quats[g, 0] + quats[g, 1] * quats[g, 1]
                      + quats[g, 2] * quats[g, 2] + quats[g, 3] * quats[g, 3])
        w, x, y, z = quats[g, 0] / n, quats[g, 1] / n, quats[g, 2] / n, quats[g, 3] / n
        s0 = math.exp(logscales[g, 0])
        s1 = math.exp(logscales[g, 1])
        s2 = math.exp(logscales[g, 2])
        m00 = (1.0 - 2.0 * (y * y + z * z)) * s0
        m01 = (2.0 * (x * y - w * z)) * s1
        m02 = (2.0 * (x * z + w * y)) * s2
        m10 = (2.0 * (x * y + w * z)) * s0
        m11 = (1.0 - 2.0 * (x * x + z * z)) * s1
        m12 = (2.0 * (y * z - w * x)) * s2
        m20 = (2.0 * (x * z - w * y)) * s0
        m21 = (2.0 * (y * z + w * x)) * s1
        m22 = (1.0 - 2.0 * (x * x + y * y)) * s2
        cov6[g, 0] = m00 * m00 + m01 * m01 + m02 * m02
        cov6[g, 1] = m00 * m10 + m01 * m11 + m02 * m12
        cov6[g, 2] = m00 * m20 + m01 * m21 + m02 * m22
        cov6[g, 3] = m10 * m10 + m11 * m11 + m12 * m12
        cov6[g, 4] = m10 * m20 + m11 * m21 + m12 * m22
        cov6[g, 5] = m20 * m20 + m21 * m21 + m22 * m22


@njit(inline="always", cache=True, fastmath=False)
def project_one(g, means, cov6, V, t0, t1, t2, fx, fy, cx, cy, width, height, near, far,
                lim_xp, lim_xn, lim_yp, lim_yn, means2d, conics, depths, radii):
    """Project Gaussian g (see module docstring); writes row g of the outputs."""
    radii[g] = 0
    means2d[g, 0] = 0.0
    means2d[g, 1] = 0.0
    conics[g, 0] = 0.0
    conics[g, 1] = 0.0
    conics[g, 2] = 0.0
    mx, my, mz = float(means[g, 0]), float(means[g, 1]), float(means[g, 2])
    x = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + t0
    y = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + t1
    z = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + t2
    depths[g] = z
    if not (z >= near and z <= far):
        return
    # Sc = V S3 V^T, in the order of _cov_cam (tmp = V S3, then tmp V^T); S3
    # symmetric, stored as its upper triangle (00, 01, 02, 11, 12, 22)
    c00, c01, c02 = cov6[g, 0], cov6[g, 1], cov6[g, 2]
    c11, c12, c22 = cov6[g, 3], cov6[g, 4], cov6[g, 5]
    tm00 = V[0, 0] * c00 + V[0, 1] * c01 + V[0, 2] * c02
    tm01 = V[0, 0] * c01 + V[0, 1] * c11 + V[0, 2] * c12
    tm02 = V[0, 0] * c02 + V[0, 1] * c12 + V[0, 2] * c22
    tm10 = V[1, 0] * c00 + V[1, 1] * c01 + V[1, 2] * c02
    tm11 = V[1, 0] * c01 + V[1, 1] * c11 + V[1, 2] * c12
    tm12 = V[1, 0] * c02 + V[1, 1] * c12 + V[1, 2] * c22
    tm20 = V[2, 0] * c00 + V[2, 1] * c01 + V[2, 2] * c02
    tm21 = V[2, 0] * c01 + V[2, 1] * c11 + V[2, 2] * c12
    tm22 = V[2, 0] * c02 + V[2, 1] * c12 + V[2, 2] * c22
    s00 = tm00 * V[0, 0] + tm01 * V[0, 1] + tm02 * V[0, 2]
    s01 = tm00 * V[1, 0] + tm01 * V[1, 1] + tm02 * V[1, 2]
    s02 = tm00 * V[2, 0] + tm01 * V[2, 1] + tm02 * V[2, 2]
    s11 = tm10 * V[1, 0] + tm11 * V[1, 1] + tm12 * V[1, 2]
    s12 = tm10 * V[2, 0] + tm11 * V[2, 1] + tm12 * V[2, 2]
    s21 = tm20 * V[1, 0] + tm21 * V[1, 1] + tm22 * V[1, 2]
    s22 = tm20 * V[2, 0] + tm21 * V[2, 1] + tm22 * V[2, 2]
    rz = 1.0 / z
    tx = z * min(lim_xp, max(-lim_xn, x * rz))
    ty = z * min(lim_yp, max(-lim_yn, y * rz))
    j00 = fx * rz
    j02 = -fx * tx * rz * rz
    j11 = fy * rz
    j12 = -fy * ty * rz * rz
    # cov2d = J Sc J^T with J = [[j00, 0, j02], [0, j11, j12]]
    a = (j00 * j00 * s00 + 2.0 * j00 * j02 * s02 + j02 * j02 * s22 + LOWPASS_PX2)
    b = (j00 * j11 * s01 + j00 * j12 * s02 + j02 * j11 * s21 + j02 * j12 * s22)
    c = (j11 * j11 * s11 + 2.0 * j11 * j12 * s12 + j12 * j12 * s22 + LOWPASS_PX2)
    det = a * c - b * b
    if not (det > 0.0):
        return
    u = fx * x * rz + cx
    v = fy * y * rz + cy
    mid = 0.5 * (a + c)
    lam = mid + math.sqrt(max(0.1, mid * mid - det))
    rf = 3.0 * math.sqrt(lam)
    if not (rf < MAX_RADIUS_PX):
        rf = MAX_RADIUS_PX
    r = np.ceil(rf)
    # box of pixel centres the 3-sigma ellipse can reach
    if u + r < 0.5 or u - r > width - 0.5 or v + r < 0.5 or v - r > height - 0.5:
        return
    means2d[g, 0] = u
    means2d[g, 1] = v
    conics[g, 0] = c / det
    conics[g, 1] = -b / det
    conics[g, 2] = a / det
    radii[g] = int(r)


@njit(cache=True, fastmath=False)
def view_limits(fx, fy, cx, cy, width, height):
    """x/z, y/z clamps of the EWA Jacobian: 1.3x the field of view."""
    return ((width - cx) / fx + 0.3 * width / fx, cx / fx + 0.3 * width / fx,
            (height - cy) / fy + 0.3 * height / fy, cy / fy + 0.3 * height / fy)


@njit(parallel=True, cache=True, fastmath=False)
def project_forward_kernel(means, cov6, viewmat, fx, fy, cx, cy, width, height, near, far, idx,
                           means2d, conics, depths, radii):
    """Project the Gaussians ``idx`` (M,) int64; rows of the others are left
    untouched."""
    V = viewmat[:3, :3].copy()
    t0, t1, t2 = viewmat[0, 3], viewmat[1, 3], viewmat[2, 3]
    lim_xp, lim_xn, lim_yp, lim_yn = view_limits(fx, fy, cx, cy, width, height)
    # one prange over idx (an arange for all rows): numba compiles each
    # parallel loop separately, and a second copy of the inlined projection
    # cost ~5 of this kernel's 15 CPU-s cold compile
    for k in prange(idx.shape[0]):
        project_one(idx[k], means, cov6, V, t0, t1, t2, fx, fy, cx, cy, width, height, near, far,
                    lim_xp, lim_xn, lim_yp, lim_yn, means2d, conics, depths, radii)


@functools.lru_cache(maxsize=4)
def _every_row(n: int) -> np.ndarray:
    """0 .. n - 1, shared: callers must not write to it (a renderer projects
    every Gaussian at each pose; left writeable because numba compiles a
    read-only array as another type)."""
    return np.arange(n, dtype=np.int64)


_CHUNK = 256  # Gaussians per parallel work item of the backward


@njit(cache=True, fastmath=False)
def _project_backward_chunk(g_lo, g_hi, means, quats, logscales, V, t0, t1, t2, fx, fy,
                            lim_xp, lim_xn, lim_yp, lim_yn, radii, g_means2d, g_conics,
                            g_depths, g_means, g_quats, g_logscales):
    """:func:`project_backward_kernel` for Gaussians g_lo .. g_hi - 1 (one
    thread's chunk; its own function so that the parallel loop around it
    stays small: numba's parfor passes over this body made the cold compile
    12 instead of 4.7 CPU-s)."""
    Rq = np.empty((3, 3))
    M = np.empty((3, 3))
    S3 = np.empty((3, 3))
    Sc = np.empty((3, 3))
    q = np.empty(4)
    ls = np.empty(3)
    J = np.zeros((2, 3))
    S2 = np.empty((2, 2))
    Q = np.empty((2, 2))
    Gq = np.empty((2, 2))
    T2 = np.empty((2, 2))
    GS2 = np.empty((2, 2))
    GSc = np.empty((3, 3))
    JSc = np.empty((2, 3))
    GJ = np.empty((2, 3))
    tmp = np.empty((3, 3))
    GS3 = np.empty((3, 3))
    GM = np.empty((3, 3))
    GR = np.empty((3, 3))
    for g in range(g_lo, g_hi):
        for k in range(3):
            g_means[g, k] = 0.0
            g_logscales[g, k] = 0.0
        for k in range(4):
            g_quats[g, k] = 0.0
        if radii[g] <= 0:
            continue
        for k in range(4):
            q[k] = quats[g, k]
        for k in range(3):
            ls[k] = logscales[g, k]
        mx, my, mz = float(means[g, 0]), float(means[g, 1]), float(means[g, 2])
        x = V[0, 0] * mx + V[0, 1] * my + V[0, 2] * mz + t0
        y = V[1, 0] * mx + V[1, 1] * my + V[1, 2] * mz + t1
        z = V[2, 0] * mx + V[2, 1] * my + V[2, 2] * mz + t2
        _cov_cam(q, ls, V, Rq, M, S3, Sc)
        rz = 1.0 / z
        xr = x * rz
        yr = y * rz
        cl_x = xr < -lim_xn or xr > lim_xp
        cl_y = yr < -lim_yn or yr > lim_yp
        tx = z * min(lim_xp, max(-lim_xn, xr))
        ty = z * min(lim_yp, max(-lim_yn, yr))
        J[0, 0] = fx * rz
        J[0, 2] = -fx * tx * rz * rz
        J[1, 1] = fy * rz
        J[1, 2] = -fy * ty * rz * rz
        # cov2d and conic
        for i in range(2):
            for j in range(2):
                acc = 0.0
                for k in range(3):
                    for l in range(3):
                        acc += J[i, k] * Sc[k, l] * J[j, l]
                S2[i, j] = acc
        S2[0, 0] += LOWPASS_PX2
        S2[1, 1] += LOWPASS_PX2
        det = S2[0, 0] * S2[1, 1] - S2[0, 1] * S2[1, 0]
        Q[0, 0] = S2[1, 1] / det
        Q[0, 1] = -S2[0, 1] / det
        Q[1, 0] = Q[0, 1]
        Q[1, 1] = S2[0, 0] / det
        # conic (A, B, C) with B the off-diagonal entry, used once in the
        # symmetric matrix form -> dL/dQ has B-gradient split in half
        Gq[0, 0] = g_conics[g, 0]
        Gq[0, 1] = 0.5 * g_conics[g, 1]
        Gq[1, 0] = Gq[0, 1]
        Gq[1, 1] = g_conics[g, 2]
        # dL/dS2 = -Q Gq Q
        for i in range(2):
            for j in range(2):
                T2[i, j] = Q[i, 0] * Gq[0, j] + Q[i, 1] * Gq[1, j]
        for i in range(2):
            for j in range(2):
                GS2[i, j] = -(T2[i, 0] * Q[0, j] + T2[i, 1] * Q[1, j])
        # S2 = J Sc J^T: dL/dSc = J^T GS2 J ; dL/dJ = 2 GS2 J Sc
        for k in range(3):
            for l in range(3):
                acc = 0.0
                for i in range(2):
                    for j in range(2):
                        acc += J[i, k] * GS2[i, j] * J[j, l]
                GSc[k, l] = acc
        for i in range(2):
            for l in range(3):
                acc = 0.0
                for k in range(3):
                    acc += J[i, k] * Sc[k, l]
                JSc[i, l] = acc
        for i in range(2):
            for l in range(3):
                GJ[i, l] = 2.0 * (GS2[i, 0] * JSc[0, l] + GS2[i, 1] * JSc[1, l])
        # camera-space position gradient
        gx = 0.0
        gy = 0.0
        gz = float(g_depths[g])
        gu = float(g_means2d[g, 0])
        gv = float(g_means2d[g, 1])
        gx += gu * fx * rz
        gz += -gu * fx * x * rz * rz
        gy += gv * fy * rz
        gz += -gv * fy * y * rz * rz
        gz += -GJ[0, 0] * fx * rz * rz - GJ[1, 1] * fy * rz * rz
        gz += GJ[0, 2] * 2.0 * fx * tx * rz * rz * rz + GJ[1, 2] * 2.0 * fy * ty * rz * rz * rz
        gtx = -GJ[0, 2] * fx * rz * rz
        gty = -GJ[1, 2] * fy * rz * rz
        if cl_x:
            gz += gtx * (tx * rz)
        else:
            gx += gtx
        if cl_y:
            gz += gty * (ty * rz)
        else:
            gy += gty
        # world position: p = V m + t
        for k in range(3):
            g_means[g, k] = V[0, k] * gx + V[1, k] * gy + V[2, k] * gz
        # Sc = V S3 V^T -> GS3 = V^T GSc V
        _mul3(V, GSc, tmp, True, False)
        _mul3(tmp, V, GS3, False, False)
        # S3 = M M^T -> GM = (GS3 + GS3^T) M
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for k in range(3):
                    acc += (GS3[i, k] + GS3[k, i]) * M[k, j]
                GM[i, j] = acc
        # M = Rq diag(s)
        for j in range(3):
            s = math.exp(ls[j])
            acc = 0.0
            for i in range(3):
                GR[i, j] = GM[i, j] * s
                acc += GM[i, j] * Rq[i, j]
            g_logscales[g, j] = acc * s
        nq, w, qx, qy, qz = _quat_to_rot(q[0], q[1], q[2], q[3], Rq)
        gw = 2.0 * (-qz * GR[0, 1] + qy * GR[0, 2] + qz * GR[1, 0] - qx * GR[1, 2]
                    - qy * GR[2, 0] + qx * GR[2, 1])
        gqx = 2.0 * (qy * GR[0, 1] + qz * GR[0, 2] + qy * GR[1, 0] - 2.0 * qx * GR[1, 1]
                     - w * GR[1, 2] + qz * GR[2, 0] + w * GR[2, 1] - 2.0 * qx * GR[2, 2])
        gqy = 2.0 * (-2.0 * qy * GR[0, 0] + qx * GR[0, 1] + w * GR[0, 2] + qx * GR[1, 0]
                     + qz * GR[1, 2] - w * GR[2, 0] + qz * GR[2, 1] - 2.0 * qy * GR[2, 2])
        gqz = 2.0 * (-2.0 * qz * GR[0, 0] - w * GR[0, 1] + qx * GR[0, 2] + w * GR[1, 0]
                     - 2.0 * qz * GR[1, 1] + qy * GR[1, 2] + qx * GR[2, 0] + qy * GR[2, 1])
        dot = gw * w + gqx * qx + gqy * qy + gqz * qz
        g_quats[g, 0] = (gw - w * dot) / nq
        g_quats[g, 1] = (gqx - qx * dot) / nq
        g_quats[g, 2] = (gqy - qy * dot) / nq
        g_quats[g, 3] = (gqz - qz * dot) / nq


@njit(parallel=True, cache=True, fastmath=False)
def project_backward_kernel(means, quats, logscales, viewmat, fx, fy, cx, cy,
                            width, height, radii, g_means2d, g_conics, g_depths,
                            g_means, g_quats, g_logscales):
    """Gradients of (means2d, conics, depths) w.r.t. (means, quats, logscales).

    Only Gaussians with radii > 0 get non-zero gradients (culled ones did not
    render). The depth gradient is only used for visible Gaussians too.
    """
    n = means.shape[0]
    V = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            V[i, j] = viewmat[i, j]
    t0, t1, t2 = viewmat[0, 3], viewmat[1, 3], viewmat[2, 3]
    lim_xp = (width - cx) / fx + 0.3 * width / fx
    lim_xn = cx / fx + 0.3 * width / fx
    lim_yp = (height - cy) / fy + 0.3 * height / fy
    lim_yn = cy / fy + 0.3 * height / fy
    # scratch matrices once per chunk of Gaussians: allocating them per
    # Gaussian took 30 % of this kernel's time. J's zeros at [0, 1] and [1, 0]
    # are never overwritten.
    n_chunks = (n + _CHUNK - 1) // _CHUNK
    for ci in prange(n_chunks):
        _project_backward_chunk(ci * _CHUNK, min(n, (ci + 1) * _CHUNK), means, quats, logscales,
                                V, t0, t1, t2, fx, fy, lim_xp, lim_xn, lim_yp, lim_yn, radii,
                                g_means2d, g_conics, g_depths, g_means, g_quats, g_logscales)


def project(means, quats, logscales, viewmat, fx, fy, cx, cy, width, height,
            near=0.01, far=1.0e10):
    """Project Gaussians; numpy in, float64 numpy out.

    Parameters
    ----------
    means (N,3) world positions; quats (N,4) (w,x,y,z); logscales (N,3);
    viewmat (4,4) world-to-camera (OpenCV axes); fx, fy, cx, cy in px;
    width, height in px; near, far depth limits (camera z, scene units).

    Returns
    -------
    means2d (N,2) px, conics (N,3) inverse 2D covariance (a, b, c) in 1/px^2,
    depths (N,) camera z, radii (N,) int32 px (0 = culled).
    """
    n = means.shape[0]
    cov6 = np.empty((n, 6))
    cov3d_kernel(np.ascontiguousarray(quats, dtype=np.float64),
                 np.ascontiguousarray(logscales, dtype=np.float64), cov6)
    return project_cov(means, cov6, viewmat, fx, fy, cx, cy, width, height, near, far)


def project_cov(means, cov6, viewmat, fx, fy, cx, cy, width, height, near=0.01, far=1.0e10,
                idx=None, out=None):
    """:func:`project` from precomputed world covariances ``cov6`` (N,6)
    (:func:`cov3d_kernel`; constant for a trained model). With ``idx`` (M,)
    int64 only those Gaussians are projected into ``out`` (the four arrays of
    a previous call), the other rows are left as they are."""
    n = means.shape[0]
    if out is None:
        out = (np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, dtype=np.int32))
    means2d, conics, depths, radii = out
    project_forward_kernel(np.ascontiguousarray(means, dtype=np.float64), cov6,
                           np.ascontiguousarray(viewmat, dtype=np.float64),
                           float(fx), float(fy), float(cx), float(cy),
                           float(width), float(height), float(near), float(far),
                           _every_row(n) if idx is None else idx,
                           means2d, conics, depths, radii)
    return means2d, conics, depths, radii


def project_backward(means, quats, logscales, viewmat, fx, fy, cx, cy, width, height,
                     radii, g_means2d, g_conics, g_depths):
    """Hand-written backward of :func:`project` (float64 numpy out).

    Returns g_means (N,3), g_quats (N,4), g_logscales (N,3).
    """
    n = means.shape[0]
    g_means = np.empty((n, 3))
    g_quats = np.empty((n, 4))
    g_logscales = np.empty((n, 3))
    f64 = np.float64
    project_backward_kernel(np.ascontiguousarray(means, dtype=f64),
                            np.ascontiguousarray(quats, dtype=f64),
                            np.ascontiguousarray(logscales, dtype=f64),
                            np.ascontiguousarray(viewmat, dtype=f64),
                            float(fx), float(fy), float(cx), float(cy),
                            float(width), float(height), radii,
                            np.ascontiguousarray(g_means2d, dtype=f64),
                            np.ascontiguousarray(g_conics, dtype=f64),
                            np.ascontiguousarray(g_depths, dtype=f64),
                            g_means, g_quats, g_logscales)
    return g_means, g_quats, g_logscales
