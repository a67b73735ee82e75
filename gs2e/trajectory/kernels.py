"""Compiled evaluation of a trajectory: time -> arc length -> curve parameter -> pose.

One pass per query, no temporaries: two cubic Hermite maps and a Horner
evaluation of the 7-channel pose polynomial, then quaternion -> matrix.
Knot lookup starts from the previous query's interval, so sorted queries (the
usual case) cost O(1) each; unsorted ones fall back to binary search.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline="always")
def _locate(x, v, i):
    """Index j in [0, len(x)-2] with x[j] <= v < x[j+1] (clamped), starting at i."""
    n = x.shape[0] - 1
    if i > n - 1:
        i = n - 1
    if i < 0:
        i = 0
    if v >= x[i]:
        if i == n - 1 or v < x[i + 1]:
            return i
        if i + 1 == n - 1 or v < x[i + 2]:
            return i + 1
        lo, hi = i + 1, n - 1
    else:
        lo, hi = 0, i
    while lo < hi:
        mid = (lo + hi + 1) >> 1
        if x[mid] <= v:
            lo = mid
        else:
            hi = mid - 1
    return lo


@njit(cache=True, inline="always")
def _hermite(x, y, m, i, v):
    h = x[i + 1] - x[i]
    tau = (v - x[i]) / h
    return (y[i] + tau * tau * (3.0 - 2.0 * tau) * (y[i + 1] - y[i])
            + h * tau * (1.0 - tau) * ((1.0 - tau) * m[i] - tau * m[i + 1]))


@njit(cache=True)
def eval_poses(s, arc_L, arc_u, arc_du, breaks, coeffs, out):
    """Poses at arc lengths ``s`` (Q,) into ``out`` (Q, 4, 4).

    coeffs: (n_seg, k+1, 7) contiguous, highest power first.
    """
    Q = s.shape[0]
    nseg = coeffs.shape[0]
    kp1 = coeffs.shape[1]
    il = 0
    ib = 0
    y = np.empty(7)
    for j in range(Q):
        sj = s[j]
        il = _locate(arc_L, sj, il)
        u = _hermite(arc_L, arc_u, arc_du, il, sj)
        ib = _locate(breaks, u, ib)
        if ib > nseg - 1:
            ib = nseg - 1
        x = u - breaks[ib]
        for c in range(7):
            acc = coeffs[ib, 0, c]
            for d in range(1, kp1):
                acc = acc * x + coeffs[ib, d, c]
            y[c] = acc
        w, qx, qy, qz = y[3], y[4], y[5], y[6]
        inv = 1.0 / np.sqrt(w * w + qx * qx + qy * qy + qz * qz)
        w *= inv
        qx *= inv
        qy *= inv
        qz *= inv
        o = out[j]
        o[0, 0] = 1.0 - 2.0 * (qy * qy + qz * qz)
        o[0, 1] = 2.0 * (qx * qy - w * qz)
        o[0, 2] = 2.0 * (qx * qz + w * qy)
        o[0, 3] = y[0]
        o[1, 0] = 2.0 * (qx * qy + w * qz)
        o[1, 1] = 1.0 - 2.0 * (qx * qx + qz * qz)
        o[1, 2] = 2.0 * (qy * qz - w * qx)
        o[1, 3] = y[1]
        o[2, 0] = 2.0 * (qx * qz - w * qy)
        o[2, 1] = 2.0 * (qy * qz + w * qx)
        o[2, 2] = 1.0 - 2.0 * (qx * qx + qy * qy)
        o[2, 3] = y[2]
        o[3, 0] = 0.0
        o[3, 1] = 0.0
        o[3, 2] = 0.0
        o[3, 3] = 1.0


@njit(cache=True)
def map_times(t, tx, ty, tm, out):
    """Arc lengths at times ``t`` (Q,) through the Hermite map (tx, ty, tm) into ``out``."""
    it = 0
    for j in range(t.shape[0]):
        v = t[j]
        it = _locate(tx, v, it)
        out[j] = _hermite(tx, ty, tm, it, v)


@njit(cache=True)
def curve_speed(u, breaks, coeffs, alpha, beta, speed, qnorm):
    """Metric speed alpha*|omega| + beta*|dT/du| and quaternion-channel norm at u (Q,).

    coeffs: (n_seg, k+1, 7) contiguous, highest power first. |omega| = 2|d(p/|p|)/du|.
    """
    nseg = coeffs.shape[0]
    kp1 = coeffs.shape[1]
    ib = 0
    y = np.empty(7)
    dy = np.empty(7)
    for j in range(u.shape[0]):
        v = u[j]
        ib = _locate(breaks, v, ib)
        if ib > nseg - 1:
            ib = nseg - 1
        x = v - breaks[ib]
        for c in range(7):
            acc = coeffs[ib, 0, c]
            dacc = 0.0
            for d in range(1, kp1):
                dacc = dacc * x + acc
                acc = acc * x + coeffs[ib, d, c]
            y[c] = acc
            dy[c] = dacc
        lin = np.sqrt(dy[0] * dy[0] + dy[1] * dy[1] + dy[2] * dy[2])
        n2 = y[3] * y[3] + y[4] * y[4] + y[5] * y[5] + y[6] * y[6]
        n = np.sqrt(n2)
        pd = (y[3] * dy[3] + y[4] * dy[4] + y[5] * dy[5] + y[6] * dy[6]) / n2
        a2 = 0.0
        for c in range(3, 7):
            e = dy[c] - y[c] * pd
            a2 += e * e
        speed[j] = alpha * 2.0 * np.sqrt(a2) / n + beta * lin
        qnorm[j] = n
