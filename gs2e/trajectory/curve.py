"""Pose smoothing, the pose-displacement metric, pose curves and arc length.

A pose curve is a piecewise polynomial P(u) in 7 channels -- camera centre
(tx, ty, tz) and a sign-continuous quaternion (qw, qx, qy, qz) -- over the
curve parameter u (the cumulative displacement of its keyframes, paper eq. 3).
The rotation at u is the normalised quaternion channel: consecutive keyframe
quaternions are put on the same hemisphere, so the curve never swings through
an antipode, and it inherits the polynomial's continuity (C^2 for the cubic
B-spline). Its *true* arc length

    L(u) = int_0^u alpha * |omega(u')| + beta_n * |dT/du'| du'

(|omega| = angular speed in rad per unit u, beta_n = beta / translation scale)
is tabulated by Gauss-Legendre quadrature and inverted by a monotone cubic
Hermite interpolant, so samples can be placed at exact arc-length targets.

Polynomials use SciPy's PPoly layout: ``coeffs[d, i, c]`` multiplies
``(u - breaks[i]) ** (k - d)`` on segment i for channel c (highest power first).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BPoly, CubicHermiteSpline, CubicSpline, PPoly

from gs2e.common.errors import InputError
from gs2e.common.so3 import (geodesic_angle, quat_make_continuous, quat_mean,
                             quat_to_rotmat, rotmat_to_quat)

METHODS = ("bspline", "bezier", "linear")
N_SUB = 16          # arc-length table sub-intervals per curve segment
_GL_X, _GL_W = np.polynomial.legendre.leggauss(5)


# ---------------------------------------------------------------- input checks, smoothing

def check_c2w(c2w: np.ndarray, what: str = "poses") -> np.ndarray:
    """(N, 4, 4) float64 camera-to-world poses; InputError on bad shape or NaN/inf,
    naming the first offending pose index."""
    P = np.asarray(c2w, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (4, 4) or P.shape[0] < 1:
        raise InputError(f"{what}: expected (N>=1, 4, 4) camera-to-world poses, got shape {P.shape}")
    bad = ~np.all(np.isfinite(P), axis=(1, 2))
    if np.any(bad):
        raise InputError(f"{what}: pose {int(np.flatnonzero(bad)[0])} contains NaN or inf")
    R = P[:, :3, :3]
    err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    bad = (err > 1e-4) | (np.linalg.det(R) < 0)
    if np.any(bad):
        raise InputError(f"{what}: pose {int(np.flatnonzero(bad)[0])} is not a proper rotation")
    return P


def split_c2w(c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 4, 4) poses -> centres (N, 3), sign-continuous quaternions (N, 4)."""
    return c2w[:, :3, 3].copy(), quat_make_continuous(rotmat_to_quat(c2w[:, :3, :3]))


def join_c2w(T: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Centres (N, 3) + quaternions (N, 4) -> (N, 4, 4) camera-to-world poses."""
    out = np.zeros(T.shape[:-1] + (4, 4))
    out[..., :3, :3] = quat_to_rotmat(q)
    out[..., :3, 3] = T
    out[..., 3, 3] = 1.0
    return out


def smooth_poses(c2w: np.ndarray, half_width: int) -> np.ndarray:
    """Local pose smoothing over windows W_i = {j : |j - i| <= w, 0 <= j < N} (paper eq. 1-2).

    Centres: plain mean over the window. Rotations: quaternions flipped onto the
    hemisphere of the window's centre pose, averaged and normalised (the
    chordal mean; equal to the geodesic midpoint for two rotations). Windows
    shrink at the ends of the sequence, so there is no padding bias.

    Parameters
    ----------
    c2w : (N, 4, 4) camera-to-world poses.
    half_width : w >= 0; 0 returns a copy.
    """
    P = check_c2w(c2w)
    N = len(P)
    if half_width <= 0 or N == 1:
        return P.copy()
    T, q = split_c2w(P)
    offs = np.arange(-half_width, half_width + 1)
    idx = np.arange(N)[:, None] + offs[None, :]
    valid = (idx >= 0) & (idx < N)
    idx = np.clip(idx, 0, N - 1)
    wts = valid.astype(np.float64)
    T_s = (T[idx] * wts[..., None]).sum(1) / wts.sum(1, keepdims=True)
    q_s = quat_mean(q[idx], weights=wts, reference=q)
    return join_c2w(T_s, quat_make_continuous(q_s))


def translation_scale(c2w: np.ndarray) -> float:
    """RMS distance (scene units) of the camera centres from their mean; 1.0 when
    it is zero (one pose, or all centres equal). Makes beta scale-free."""
    T = np.asarray(c2w)[:, :3, 3]
    rms = float(np.sqrt(np.mean(np.sum((T - T.mean(0)) ** 2, axis=1)))) if len(T) > 1 else 0.0
    return rms if rms > 1e-12 else 1.0


def pose_deltas(c2w: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """delta_i = alpha * theta_i + beta * |T_{i+1} - T_i| for consecutive poses (N-1,).

    theta_i is the geodesic angle (rad) from :func:`gs2e.common.so3.geodesic_angle`
    (atan2 form, stable near 0 and pi); beta is per scene unit.
    """
    P = np.asarray(c2w, dtype=np.float64)
    if len(P) < 2:
        return np.zeros(0)
    theta = geodesic_angle(P[:-1, :3, :3], P[1:, :3, :3])
    dT = np.linalg.norm(P[1:, :3, 3] - P[:-1, :3, 3], axis=1)
    return alpha * theta + beta * dT


# ---------------------------------------------------------------- pose curves

@dataclass
class PoseCurve:
    """Piecewise polynomial P(u): breaks (n+1,), coeffs (k+1, n, 7) (PPoly layout)."""

    breaks: np.ndarray
    coeffs: np.ndarray

    @property
    def n_segments(self) -> int:
        return self.coeffs.shape[1]

    @property
    def coeffs_t(self) -> np.ndarray:
        """Coefficients as (n_seg, k+1, 7) contiguous (the kernels' layout)."""
        return np.ascontiguousarray(np.transpose(self.coeffs, (1, 0, 2)))

    def eval(self, u: np.ndarray, nu: int = 0) -> np.ndarray:
        """Channel values (nu = 0) or nu-th derivatives at u (...,) -> (..., 7)."""
        u = np.asarray(u, dtype=np.float64)
        i = np.clip(np.searchsorted(self.breaks, u, side="right") - 1, 0, self.n_segments - 1)
        x = (u - self.breaks[i])[..., None]
        k = self.coeffs.shape[0] - 1
        c = self.coeffs
        acc = np.zeros(u.shape + (7,))
        for d in range(k - nu + 1):
            p = k - d  # power of x multiplying c[d]
            fac = 1.0
            for j in range(nu):
                fac *= (p - j)
            acc = acc * x + fac * c[d, i]
        return acc

    def c2w(self, u: np.ndarray) -> np.ndarray:
        """Poses (..., 4, 4) at curve parameters u (numpy path, for small queries)."""
        y = self.eval(u)
        return join_c2w(y[..., :3], y[..., 3:] / np.linalg.norm(y[..., 3:], axis=-1, keepdims=True))


def _catmull_rom_slopes(u: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Derivatives at knots (N, C) of the parabola through each knot and its two
    neighbours (one-sided at the ends); the secant when N == 2."""
    h = np.diff(u)[:, None]
    d = np.diff(Y, axis=0) / h
    if len(u) == 2:
        return np.vstack([d, d])
    m = np.empty_like(Y)
    a, b = h[:-1], h[1:]
    m[1:-1] = (b * d[:-1] + a * d[1:]) / (a + b)
    # one-sided three-point formulas at the ends
    m[0] = ((2 * h[0] + h[1]) * d[0] - h[0] * d[1]) / (h[0] + h[1])
    m[-1] = ((2 * h[-1] + h[-2]) * d[-1] - h[-1] * d[-2]) / (h[-1] + h[-2])
    return m


def fit_curve(u: np.ndarray, T: np.ndarray, q: np.ndarray, method: str = "bspline") -> PoseCurve:
    """Interpolating pose curve through keyframes at strictly increasing u.

    method:
      - ``bspline``: C^2 cubic interpolating spline (not-a-knot ends); quadratic
        for 3 keyframes, linear for 2 (paper default);
      - ``bezier``: piecewise cubic Bezier with Catmull-Rom handles (C^1, the
        ablation's Bezier interpolation);
      - ``linear``: piecewise linear centres, normalised-linear quaternions
        (the geodesic path between keyframes; C^0).
    A single keyframe gives a constant curve on [0, 1].
    """
    u = np.asarray(u, dtype=np.float64)
    Y = np.concatenate([T, quat_make_continuous(q)], axis=1)
    if len(u) == 1:
        return PoseCurve(np.array([0.0, 1.0]), Y[None, :1, :].copy())
    if np.any(np.diff(u) <= 0):
        raise ValueError("curve knots must be strictly increasing")
    if method == "linear" or len(u) == 2:
        c = np.stack([np.diff(Y, axis=0) / np.diff(u)[:, None], Y[:-1]])
        return PoseCurve(u.copy(), c)
    if method == "bspline":
        pp = CubicSpline(u, Y, axis=0, bc_type="not-a-knot")
    elif method == "bezier":
        pp = CubicHermiteSpline(u, Y, _catmull_rom_slopes(u, Y), axis=0)
    else:
        raise ValueError(f"unknown interpolation method {method!r} (one of {METHODS})")
    return PoseCurve(np.asarray(pp.x, np.float64), np.asarray(pp.c, np.float64))


def fit_bezier(u: np.ndarray, T: np.ndarray, q: np.ndarray, degree: int) -> PoseCurve:
    """Single least-squares Bezier curve of ``degree`` over [u_0, u_{K-1}] through
    the first and last keyframe (end control points fixed), approximating the
    inner ones at their parameters u. The degree is capped at K-1 (interpolation)."""
    u = np.asarray(u, dtype=np.float64)
    Y = np.concatenate([T, quat_make_continuous(q)], axis=1)
    K = len(u)
    d = int(min(degree, K - 1))
    if K < 2:
        return fit_curve(u, T, q)
    x = (u - u[0]) / (u[-1] - u[0])
    from scipy.special import comb
    j = np.arange(d + 1)
    A = comb(d, j) * x[:, None] ** j * (1 - x[:, None]) ** (d - j)
    C = np.empty((d + 1, 7))
    C[0], C[-1] = Y[0], Y[-1]
    if d > 1:
        rhs = Y - A[:, :1] * Y[0] - A[:, -1:] * Y[-1]
        C[1:-1] = np.linalg.lstsq(A[:, 1:-1], rhs, rcond=None)[0]
    pp = PPoly.from_bernstein_basis(BPoly(C[:, None, :], [u[0], u[-1]]))
    return PoseCurve(np.asarray(pp.x, np.float64), np.asarray(pp.c, np.float64))


# ---------------------------------------------------------------- arc length

def curve_speed(curve: PoseCurve, u: np.ndarray, alpha: float, beta: float,
                return_qnorm: bool = False):
    """Metric speed dL/du = alpha*|omega| + beta*|dT/du| at u (Q,) (compiled).

    |omega| = 2 |d/du (p/|p|)| for the quaternion channels p (rad per unit u).
    With ``return_qnorm`` also returns |p| (Q,), which must stay away from 0.
    """
    from gs2e.trajectory import kernels

    u = np.ascontiguousarray(u, dtype=np.float64).ravel()
    speed = np.empty_like(u)
    qn = np.empty_like(u)
    kernels.curve_speed(u, curve.breaks, curve.coeffs_t, float(alpha), float(beta), speed, qn)
    return (speed, qn) if return_qnorm else speed


def curve_speed_numpy(curve: PoseCurve, u: np.ndarray, alpha: float, beta: float) -> np.ndarray:
    """Reference (numpy) version of :func:`curve_speed`, used by the tests."""
    y = curve.eval(u)
    dy = curve.eval(u, nu=1)
    lin = np.linalg.norm(dy[..., :3], axis=-1)
    p, dp = y[..., 3:], dy[..., 3:]
    n = np.linalg.norm(p, axis=-1, keepdims=True)
    qn = p / n
    dq = (dp - qn * np.sum(qn * dp, axis=-1, keepdims=True)) / n
    return alpha * 2.0 * np.linalg.norm(dq, axis=-1) + beta * lin


@dataclass
class ArcTable:
    """Monotone cubic Hermite map s (true arc length) -> u: nodes L (m,), u (m,), du/ds (m,)."""

    L: np.ndarray
    u: np.ndarray
    du: np.ndarray
    min_quat_norm: float = 1.0

    @property
    def total(self) -> float:
        """Total arc length; 0 for the degenerate map of a constant curve."""
        return 0.0 if self.u[0] == self.u[-1] else float(self.L[-1])


def hermite_eval(x: np.ndarray, y: np.ndarray, m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Cubic Hermite interpolant through (x, y) with slopes m, at v (numpy)."""
    i = np.clip(np.searchsorted(x, v, side="right") - 1, 0, len(x) - 2)
    h = x[i + 1] - x[i]
    tau = (v - x[i]) / h
    return (y[i] + tau * tau * (3 - 2 * tau) * (y[i + 1] - y[i])
            + h * tau * (1 - tau) * ((1 - tau) * m[i] - tau * m[i + 1]))


def monotone_slopes(x: np.ndarray, y: np.ndarray, m: np.ndarray | None = None) -> np.ndarray:
    """Slopes for a monotone C^1 cubic Hermite interpolant of increasing data.

    With ``m`` (exact derivatives) they are kept where they satisfy the
    Fritsch-Carlson bound 0 <= m <= 3 * min(adjacent secants) and clipped
    otherwise; without, Fritsch-Butland (PCHIP) slopes are used.
    """
    h = np.diff(x)
    d = np.diff(y) / h
    n = len(x)
    if n == 2:
        return np.array([d[0], d[0]])
    if m is None:
        m = np.empty(n)
        w1, w2 = 2 * h[1:] + h[:-1], h[1:] + 2 * h[:-1]
        with np.errstate(divide="ignore", invalid="ignore"):
            hm = (w1 + w2) / (w1 / d[:-1] + w2 / d[1:])
        m[1:-1] = np.where((d[:-1] > 0) & (d[1:] > 0), hm, 0.0)
        m[0] = ((2 * h[0] + h[1]) * d[0] - h[0] * d[1]) / (h[0] + h[1])
        m[-1] = ((2 * h[-1] + h[-2]) * d[-1] - h[-1] * d[-2]) / (h[-1] + h[-2])
    lim = np.empty(n)
    lim[1:-1] = 3.0 * np.minimum(d[:-1], d[1:])
    lim[0], lim[-1] = 3.0 * d[0], 3.0 * d[-1]
    return np.clip(np.nan_to_num(m, nan=0.0, posinf=np.inf), 0.0, lim)


def _gl_integral(curve: PoseCurve, a: np.ndarray, b: np.ndarray, alpha: float,
                 beta: float) -> np.ndarray:
    """5-point Gauss-Legendre integral of the metric speed over [a_i, b_i]."""
    mid, half = 0.5 * (a + b), 0.5 * (b - a)
    gx = mid[:, None] + half[:, None] * _GL_X
    sp = curve_speed(curve, gx.ravel(), alpha, beta).reshape(gx.shape)
    return (sp * _GL_W).sum(-1) * half


def arc_length_table(curve: PoseCurve, alpha: float, beta: float, n_sub: int = N_SUB,
                     rtol: float = 1e-8, max_sub: int = 4096) -> ArcTable:
    """Tabulate the true arc length of ``curve`` and build the inverse map s -> u.

    Each curve segment is cut into n_sub (initially ``n_sub``) equal pieces
    integrated by 5-point Gauss-Legendre; the Hermite inverse is checked at every
    piece's midpoint and segments whose arc-length error exceeds ``rtol`` of the
    piece's length are refined (up to ``max_sub`` pieces per segment), so the
    samples land on their arc-length targets to ~1e-8 relative per piece.
    A constant curve (one keyframe) gives a degenerate map sending every s to
    u = breaks[0].
    """
    br = curve.breaks
    nseg = curve.n_segments
    if curve.coeffs.shape[0] == 1:  # constant curve
        return ArcTable(np.array([0.0, 1.0]), np.array([br[0], br[0]]), np.zeros(2))
    counts = np.full(nseg, int(n_sub))
    while True:
        seg = np.repeat(np.arange(nseg), counts)
        first = np.concatenate([[0], np.cumsum(counts)[:-1]])
        k = np.arange(seg.size) - first[seg]
        h = np.diff(br)[seg] / counts[seg]
        a = br[seg] + k * h
        b = np.where(k == counts[seg] - 1, br[seg + 1], a + h)
        pieces = _gl_integral(curve, a, b, alpha, beta)
        L = np.concatenate([[0.0], np.cumsum(pieces)])
        u = np.concatenate([a, [br[-1]]])
        speed_nodes, qn_nodes = curve_speed(curve, u, alpha, beta, return_qnorm=True)
        keep = np.concatenate([[True], pieces > 0])
        Lk, uk = L[keep], u[keep]
        if len(Lk) < 2:
            raise InputError("trajectory has zero length after fitting (all poses identical?)")
        with np.errstate(divide="ignore"):
            du = monotone_slopes(Lk, uk, 1.0 / speed_nodes[keep])
        # a posteriori check at piece midpoints
        m = 0.5 * (a + b)
        L_mid = L[:-1] + _gl_integral(curve, a, m, alpha, beta)
        u_hat = hermite_eval(Lk, uk, du, L_mid)
        sp_mid, qn_mid = curve_speed(curve, m, alpha, beta, return_qnorm=True)
        err = np.abs(u_hat - m) * sp_mid
        ratio = err / (rtol * np.maximum(pieces, 1e-300))
        worst = np.zeros(nseg)
        np.maximum.at(worst, seg, ratio)
        bad_seg = np.flatnonzero((worst > 1.0) & (counts < max_sub))
        if bad_seg.size == 0:
            break
        # the relative error of a piece shrinks like h^3: jump to the count that
        # should pass (rounded up to a power of two) instead of doubling blindly
        grow = 2.0 ** np.ceil(np.log2(np.cbrt(1.5 * worst[bad_seg])))
        counts[bad_seg] = np.minimum(counts[bad_seg] * np.maximum(grow, 2).astype(np.int64), max_sub)
    return ArcTable(Lk, uk, du, float(min(qn_nodes.min(), qn_mid.min())))
