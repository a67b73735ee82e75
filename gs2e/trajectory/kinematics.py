"""Exact time derivatives of a :class:`~gs2e.trajectory.trajectory.Trajectory`.

A trajectory is the composition of three piecewise-polynomial maps (module
docstring of :mod:`gs2e.trajectory.trajectory`)::

    t --(cubic Hermite)--> s --(cubic Hermite)--> u --(polynomial)--> (T, p)

with T the camera centre and p the unnormalised quaternion channel
(q = p / |p|). Inside every piece each map is a polynomial, so the first and
second time derivatives follow exactly by the chain rule:

    dT/dt   = T_u u_s s_t
    d2T/dt2 = T_uu (u_s s_t)^2 + T_u (u_ss s_t^2 + u_s s_tt)

and the same for p. The body (camera-frame) angular velocity and acceleration
of the rotation R(q) (camera-to-world, q = (w, x, y, z) taking camera vectors
to world ones) are omega = 2 vec(conj(q) q'), alpha = 2 vec(conj(q) q'')
(Sola, "Quaternion kinematics for the error-state Kalman filter", 2017,
eqs. 101 and 103; the scalar part of conj(q') q' drops out).

The maps are C^1 where they join (Hermite interpolants with shared slopes),
not C^2: the acceleration can jump at the time map's samples and at the arc
table's nodes. :func:`acceleration_jumps` measures those jumps from both
one-sided limits, so that what an IMU sees there is stated, not hidden.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gs2e.common.so3 import quat_to_rotmat

US = 1e-6  # seconds per microsecond


@dataclass(frozen=True)
class Kinematics:
    """Pose and its exact derivatives at query times.

    Attributes
    ----------
    t_us : (Q,) float64 query times, microseconds.
    c2w : (Q, 4, 4) camera-to-world poses (OpenCV axes), equal to
        ``Trajectory.pose_at`` (to rounding).
    velocity_w : (Q, 3) camera-centre velocity in the world frame, scene units/s.
    accel_w : (Q, 3) camera-centre acceleration in the world frame, scene units/s^2.
    omega_c : (Q, 3) angular velocity in the camera frame, rad/s.
    alpha_c : (Q, 3) angular acceleration in the camera frame, rad/s^2.
    """

    t_us: np.ndarray
    c2w: np.ndarray
    velocity_w: np.ndarray
    accel_w: np.ndarray
    omega_c: np.ndarray
    alpha_c: np.ndarray


def _interval(x: np.ndarray, v: np.ndarray, side: str) -> np.ndarray:
    """Piece index j of each v: x[j] <= v < x[j+1] (``side='right'``, the
    evaluation kernels' choice) or x[j] < v <= x[j+1] (``'left'``), clamped."""
    return np.clip(np.searchsorted(x, v, side=side) - 1, 0, len(x) - 2)


def hermite_derivatives(x: np.ndarray, y: np.ndarray, m: np.ndarray, v: np.ndarray,
                        side: str = "right") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Value, first and second derivative (per unit of x) of the cubic
    Hermite interpolant through (x, y) with slopes m at v (Q,); the same
    polynomial pieces as :func:`gs2e.trajectory.curve.hermite_eval`. ``side``
    picks the piece at a node (its right or left limit)."""
    i = _interval(x, v, side)
    h = x[i + 1] - x[i]
    tau = (v - x[i]) / h
    d = y[i + 1] - y[i]
    mi, mj = m[i], m[i + 1]
    val = (y[i] + tau * tau * (3 - 2 * tau) * d
           + h * tau * (1 - tau) * ((1 - tau) * mi - tau * mj))
    d1 = (6 * tau * (1 - tau) * d / h + mi * (1 - 4 * tau + 3 * tau * tau)
          + mj * (3 * tau * tau - 2 * tau))
    d2 = ((6 - 12 * tau) * d / (h * h) + (mi * (6 * tau - 4) + mj * (6 * tau - 2)) / h)
    return val, d1, d2


def _poly_derivatives(breaks: np.ndarray, coeffs: np.ndarray, u: np.ndarray, side: str):
    """Channels (Q, 7) of the pose polynomial (PPoly layout (k+1, n, 7)) and
    their first and second derivatives in u."""
    n = coeffs.shape[1]
    i = np.clip(np.searchsorted(breaks, u, side=side) - 1, 0, n - 1)
    x = (u - breaks[i])[:, None]
    k = coeffs.shape[0] - 1
    y = np.zeros((len(u), 7))
    y1 = np.zeros_like(y)
    y2 = np.zeros_like(y)
    for d in range(k + 1):  # Horner for the value and both derivatives at once
        y2 = y2 * x + 2 * y1
        y1 = y1 * x + y
        y = y * x + coeffs[d, i]
    return y, y1, y2


def _quat_conj_mul_vec(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Vector part (Q, 3) of conj(q) * r for quaternions (Q, 4) (w, x, y, z)."""
    w, v = q[:, :1], q[:, 1:]
    rw, rv = r[:, :1], r[:, 1:]
    return w * rv - rw * v - np.cross(v, rv)


def kinematics_at(traj, t_us: np.ndarray, side: str = "right") -> Kinematics:
    """Pose, velocity, acceleration, angular velocity and acceleration of
    ``traj`` at times ``t_us`` (Q,) microseconds, exactly (chain rule through
    the trajectory's pieces; see the module docstring).

    ``side`` chooses the piece at a knot: ``'right'`` (the limit from later
    times; what ``pose_at`` uses) or ``'left'``. Raises ValueError for times
    outside the trajectory or non-finite times (as ``pose_at``). A trajectory
    of one sample is at rest.
    """
    t = np.ascontiguousarray(np.atleast_1d(t_us), dtype=np.float64)
    s0 = traj.arc_length_at(t)  # checks the range and finiteness
    tx = traj.t_us.astype(np.float64)
    if len(tx) >= 2:
        _, s_t, s_tt = hermite_derivatives(tx, traj.s, traj.ds_dt, t, side)
        s_t, s_tt = s_t / US, s_tt / (US * US)  # per second
    else:
        s_t = s_tt = np.zeros_like(t)
    arc = traj.arc
    if arc.u[0] == arc.u[-1]:  # a constant curve: no arc length to map
        u, u_s, u_ss = np.full_like(t, arc.u[0]), np.zeros_like(t), np.zeros_like(t)
    else:
        u, u_s, u_ss = hermite_derivatives(arc.L, arc.u, arc.du, s0, side)
    y, y1, y2 = _poly_derivatives(traj.curve.breaks, traj.curve.coeffs, u, side)
    du_dt = (u_s * s_t)[:, None]
    d2u_dt2 = (u_ss * s_t * s_t + u_s * s_tt)[:, None]
    dy = y1 * du_dt
    d2y = y2 * du_dt * du_dt + y1 * d2u_dt2
    p, dp, d2p = y[:, 3:], dy[:, 3:], d2y[:, 3:]
    n = np.linalg.norm(p, axis=1, keepdims=True)
    pd = np.sum(p * dp, axis=1, keepdims=True)
    q = p / n
    dq = dp / n - p * pd / n ** 3
    d2q = (d2p / n - 2 * dp * pd / n ** 3
           - p * (np.sum(dp * dp, axis=1, keepdims=True) + np.sum(p * d2p, axis=1, keepdims=True)) / n ** 3
           + 3 * p * pd * pd / n ** 5)
    c2w = np.zeros((len(t), 4, 4))
    c2w[:, :3, :3] = quat_to_rotmat(p)  # normalises p as q is: the same bytes
    c2w[:, :3, 3] = y[:, :3]
    c2w[:, 3, 3] = 1.0
    return Kinematics(t, c2w, dy[:, :3], d2y[:, :3], 2 * _quat_conj_mul_vec(q, dq),
                      2 * _quat_conj_mul_vec(q, d2q))


def knot_times_us(traj) -> np.ndarray:
    """Times (float64 us, sorted, inside the trajectory) where a piece of one
    of the maps ends, i.e. where the acceleration may jump: the time map's
    samples, and the times the path passes the arc table's nodes and the
    pose curve's breaks (solved on each time-map piece by bisection; a path
    travelled back and forth passes a node once per leg)."""
    tx = traj.t_us.astype(np.float64)
    out = [tx[1:-1]]
    arc = traj.arc
    if len(tx) >= 2 and arc.u[0] != arc.u[-1]:
        # arc lengths where a piece of s -> u or of the pose curve ends
        L_curve = np.interp(traj.curve.breaks[1:-1], arc.u, arc.L)
        nodes = np.unique(np.concatenate([arc.L[1:-1], L_curve]))
        s = traj.s
        lo, hi = np.minimum(s[:-1], s[1:]), np.maximum(s[:-1], s[1:])
        j, k = np.nonzero((nodes[None, :] > lo[:, None]) & (nodes[None, :] < hi[:, None]))
        if len(j):
            a, b = tx[j].copy(), tx[j + 1].copy()
            target, rising = nodes[k], s[j + 1] > s[j]
            for _ in range(60):  # s is monotone on each piece (Fritsch-Carlson slopes)
                mid = 0.5 * (a + b)
                below = hermite_derivatives(tx, s, traj.ds_dt, mid)[0] < target
                go_right = below == rising
                a = np.where(go_right, mid, a)
                b = np.where(go_right, b, mid)
            out.append(0.5 * (a + b))
    return np.unique(np.concatenate(out))


def acceleration_jumps(traj, metres_per_unit: float = 1.0) -> dict:
    """Where ``traj`` is not C^2 and by how much: the jump of the camera
    centre's acceleration |a(t+) - a(t-)| (m/s^2, with ``metres_per_unit``
    metres per scene unit) and of the angular acceleration (rad/s^2) at every
    knot (:func:`knot_times_us`), and, for scale, the RMS of each over the
    path (sampled at 1 kHz). Velocities are continuous (C^1); their largest
    jump is reported as a check.

    Returns a dict: n_knots, accel_jump_max_m_s2, accel_jump_max_t_us,
    accel_rms_m_s2, alpha_jump_max_rad_s2, alpha_rms_rad_s2,
    velocity_jump_max_m_s (rounding), c2 (True when no jump exceeds 1e-6 of
    the RMS).
    """
    knots = knot_times_us(traj)
    t0, t1 = float(traj.t_us[0]), float(traj.t_us[-1])
    grid = np.linspace(t0, t1, max(2, int((t1 - t0) * 1e-3) + 1))
    ref = kinematics_at(traj, grid)
    a_rms = float(np.sqrt(np.mean(np.sum(ref.accel_w ** 2, axis=1)))) * metres_per_unit
    al_rms = float(np.sqrt(np.mean(np.sum(ref.alpha_c ** 2, axis=1))))
    out = {"n_knots": int(len(knots)), "accel_rms_m_s2": a_rms, "alpha_rms_rad_s2": al_rms,
           "accel_jump_max_m_s2": 0.0, "accel_jump_max_t_us": None, "alpha_jump_max_rad_s2": 0.0,
           "velocity_jump_max_m_s": 0.0}
    if len(knots):
        r, l_ = kinematics_at(traj, knots, "right"), kinematics_at(traj, knots, "left")
        ja = np.linalg.norm(r.accel_w - l_.accel_w, axis=1) * metres_per_unit
        jal = np.linalg.norm(r.alpha_c - l_.alpha_c, axis=1)
        jv = np.linalg.norm(r.velocity_w - l_.velocity_w, axis=1) * metres_per_unit
        out.update(accel_jump_max_m_s2=float(ja.max()), accel_jump_max_t_us=float(knots[int(ja.argmax())]),
                   alpha_jump_max_rad_s2=float(jal.max()), velocity_jump_max_m_s=float(jv.max()))
    out["c2"] = bool(out["accel_jump_max_m_s2"] <= 1e-6 * max(a_rms, 1e-12)
                     and out["alpha_jump_max_rad_s2"] <= 1e-6 * max(al_rms, 1e-12))
    return out
