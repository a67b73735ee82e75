"""Real spherical harmonics (degree 0-3) for view-dependent colour, with backward.

Basis ordering and signs follow the 3DGS convention (the one stored in the
official ``point_cloud.ply``: f_dc is degree 0, f_rest holds degrees 1-3 in
order), so colour = sum_k Y_k(d) * c_k + 0.5, clamped at >= 0.

All kernels work per Gaussian in float64 internally (cheap: O(N * K)) and are
compiled with numba; ``prange`` over Gaussians, no shared writes, so results
are bit-identical between runs.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
      -1.0925484305920792, 0.5462742152960396)
C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
      0.3731763325901154, -0.4570457994644658, 1.445305721320277,
      -0.5900435899266435)


def num_sh_bases(degree: int) -> int:
    """Number of SH coefficients K for a degree (0..3)."""
    if not 0 <= degree <= 3:
        raise ValueError(f"SH degree must be 0..3, got {degree}")
    return (degree + 1) ** 2


@njit(cache=True, fastmath=False)
def _basis(x, y, z, nb, out):
    """Fill out[:nb] with Y_k(x, y, z) for a unit direction."""
    out[0] = C0
    if nb > 1:
        out[1] = -C1 * y
        out[2] = C1 * z
        out[3] = -C1 * x
    if nb > 4:
        xx, yy, zz = x * x, y * y, z * z
        out[4] = C2[0] * x * y
        out[5] = C2[1] * y * z
        out[6] = C2[2] * (2.0 * zz - xx - yy)
        out[7] = C2[3] * x * z
        out[8] = C2[4] * (xx - yy)
    if nb > 9:
        xx, yy, zz = x * x, y * y, z * z
        out[9] = C3[0] * y * (3.0 * xx - yy)
        out[10] = C3[1] * x * y * z
        out[11] = C3[2] * y * (4.0 * zz - xx - yy)
        out[12] = C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy)
        out[13] = C3[4] * x * (4.0 * zz - xx - yy)
        out[14] = C3[5] * z * (xx - yy)
        out[15] = C3[6] * x * (xx - 3.0 * yy)


@njit(cache=True, fastmath=False)
def _basis_grad(x, y, z, nb, gx, gy, gz):
    """Partial derivatives dY_k/dx, dY_k/dy, dY_k/dz (unconstrained x, y, z)."""
    for k in range(nb):
        gx[k] = 0.0
        gy[k] = 0.0
        gz[k] = 0.0
    if nb > 1:
        gy[1] = -C1
        gz[2] = C1
        gx[3] = -C1
    if nb > 4:
        gx[4] = C2[0] * y
        gy[4] = C2[0] * x
        gy[5] = C2[1] * z
        gz[5] = C2[1] * y
        gx[6] = -2.0 * C2[2] * x
        gy[6] = -2.0 * C2[2] * y
        gz[6] = 4.0 * C2[2] * z
        gx[7] = C2[3] * z
        gz[7] = C2[3] * x
        gx[8] = 2.0 * C2[4] * x
        gy[8] = -2.0 * C2[4] * y
    if nb > 9:
        xx, yy, zz = x * x, y * y, z * z
        gx[9] = C3[0] * 6.0 * x * y
        gy[9] = C3[0] * (3.0 * xx - 3.0 * yy)
        gx[10] = C3[1] * y * z
        gy[10] = C3[1] * x * z
        gz[10] = C3[1] * x * y
        gx[11] = -2.0 * C3[2] * x * y
        gy[11] = C3[2] * (4.0 * zz - xx - 3.0 * yy)
        gz[11] = 8.0 * C3[2] * y * z
        gx[12] = -6.0 * C3[3] * x * z
        gy[12] = -6.0 * C3[3] * y * z
        gz[12] = C3[3] * (6.0 * zz - 3.0 * xx - 3.0 * yy)
        gx[13] = C3[4] * (4.0 * zz - 3.0 * xx - yy)
        gy[13] = -2.0 * C3[4] * x * y
        gz[13] = 8.0 * C3[4] * x * z
        gx[14] = 2.0 * C3[5] * x * z
        gy[14] = -2.0 * C3[5] * y * z
        gz[14] = C3[5] * (xx - yy)
        gx[15] = C3[6] * (3.0 * xx - 3.0 * yy)
        gy[15] = -6.0 * C3[6] * x * y


@njit(parallel=True, cache=True, fastmath=False)
def sh_forward_kernel(dirs, coeffs, nb, colors):
    """colors[i] = max(sum_k Y_k(dirs[i]/|dirs[i]|) coeffs[i,k] + 0.5, 0).

    dirs (N,3) unnormalised view directions (Gaussian centre - camera centre);
    coeffs (N,K,3); nb <= K bases used (active degree); colors (N,3) output.
    """
    n = dirs.shape[0]
    for i in prange(n):
        basis = np.empty(16)
        dx, dy, dz = float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2])
        nrm = math.sqrt(dx * dx + dy * dy + dz * dz)
        if nrm > 0.0:
            dx, dy, dz = dx / nrm, dy / nrm, dz / nrm
        _basis(dx, dy, dz, nb, basis)
        for c in range(3):
            acc = 0.0
            for k in range(nb):
                acc += basis[k] * coeffs[i, k, c]
            acc += 0.5
            colors[i, c] = acc if acc >= 0.0 else 0.0


@njit(parallel=True, cache=True, fastmath=False)
def sh_backward_kernel(dirs, coeffs, nb, colors_raw_ok, g_colors, g_coeffs, g_dirs):
    """Backward of :func:`sh_forward_kernel`.

    colors_raw_ok (N,3) bool: the unclamped colour was >= 0 (gradient passes).
    g_colors (N,3) upstream gradient; writes g_coeffs (N,K,3) (zero beyond nb)
    and g_dirs (N,3), the gradient w.r.t. the unnormalised direction.
    """
    n = dirs.shape[0]
    K = coeffs.shape[1]
    for i in prange(n):
        basis = np.empty(16)
        gx = np.empty(16)
        gy = np.empty(16)
        gz = np.empty(16)
        vx, vy, vz = float(dirs[i, 0]), float(dirs[i, 1]), float(dirs[i, 2])
        nrm = math.sqrt(vx * vx + vy * vy + vz * vz)
        x, y, z = vx, vy, vz
        if nrm > 0.0:
            x, y, z = vx / nrm, vy / nrm, vz / nrm
        _basis(x, y, z, nb, basis)
        g = np.zeros(3)
        for c in range(3):
            if colors_raw_ok[i, c]:
                g[c] = g_colors[i, c]
        for k in range(K):
            for c in range(3):
                g_coeffs[i, k, c] = basis[k] * g[c] if k < nb else 0.0
        if nb <= 1 or nrm == 0.0:
            g_dirs[i, 0] = 0.0
            g_dirs[i, 1] = 0.0
            g_dirs[i, 2] = 0.0
            continue
        _basis_grad(x, y, z, nb, gx, gy, gz)
        # dL/d(unit dir)
        ux = 0.0
        uy = 0.0
        uz = 0.0
        for k in range(1, nb):
            s = 0.0
            for c in range(3):
                s += coeffs[i, k, c] * g[c]
            ux += gx[k] * s
            uy += gy[k] * s
            uz += gz[k] * s
        # through normalisation d = v/|v|: (g - d (d.g)) / |v|
        dot = ux * x + uy * y + uz * z
        g_dirs[i, 0] = (ux - x * dot) / nrm
        g_dirs[i, 1] = (uy - y * dot) / nrm
        g_dirs[i, 2] = (uz - z * dot) / nrm


def sh_to_color(dirs: np.ndarray, coeffs: np.ndarray, degree: int):
    """Evaluate view-dependent colour.

    Parameters
    ----------
    dirs : (N,3) float array, Gaussian centre minus camera centre (any length).
    coeffs : (N,K,3) float array, SH coefficients, K >= (degree+1)**2.
    degree : active SH degree 0..3.

    Returns
    -------
    colors : (N,3) float64, clamped at >= 0.
    ok : (N,3) bool, True where the unclamped colour was >= 0.
    """
    nb = num_sh_bases(degree)
    if coeffs.shape[1] < nb:
        raise ValueError(f"SH degree {degree} needs {nb} coefficients, got {coeffs.shape[1]}")
    colors = np.empty((dirs.shape[0], 3), dtype=np.float64)
    sh_forward_kernel(np.ascontiguousarray(dirs, dtype=np.float64),
                      np.ascontiguousarray(coeffs, dtype=np.float64), nb, colors)
    # the clamp is at exactly 0 after adding 0.5; colours > 0 passed unclamped
    ok = colors > 0.0
    return colors, ok


def sh_to_color_backward(dirs, coeffs, degree, ok, g_colors):
    """Gradients (g_coeffs (N,K,3), g_dirs (N,3)) float64 of :func:`sh_to_color`."""
    nb = num_sh_bases(degree)
    g_coeffs = np.empty(coeffs.shape, dtype=np.float64)
    g_dirs = np.empty((dirs.shape[0], 3), dtype=np.float64)
    sh_backward_kernel(np.ascontiguousarray(dirs, dtype=np.float64),
                       np.ascontiguousarray(coeffs, dtype=np.float64), nb,
                       np.ascontiguousarray(ok),
                       np.ascontiguousarray(g_colors, dtype=np.float64),
                       g_coeffs, g_dirs)
    return g_coeffs, g_dirs
