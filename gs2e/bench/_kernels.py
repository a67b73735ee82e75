"""Compiled (numba) event integrators of the benchmark baselines.

Events come as parallel arrays sorted by time: ``t_us`` float64 or int64
microseconds, ``x``/``y`` pixel column/row, ``inc`` float64 the signed
log-intensity step of each event (+theta_on for ON, -theta_off for OFF). Each
event changes its pixel's log intensity at its own time: the signal is
piecewise constant between a pixel's events. Serial loops over events: a
pixel's events must be taken in time order, and one exposure or inter-frame
window holds few events per pixel.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# exp() arguments are clamped here: beyond it float64 overflows; a real log
# intensity spans ~log(1 / eps) < 10, so only noise drives sums that far.
_EXP_MAX = 700.0


@njit(inline="always", cache=True)
def _exp(v):
    return math.exp(min(max(v, -_EXP_MAX), _EXP_MAX))


@njit(cache=True)
def exposure_mean_exp(t_us, x, y, inc, t0_us, t1_us, t_ref_us, H, W):
    """Per pixel, (1/T) * integral over [t0, t1] of exp(E(tau) - E(t_ref)) dtau,
    E(tau) the sum of ``inc`` of the pixel's events with t <= tau, T = t1 - t0.

    Exact for the piecewise-constant event signal (no sub-frame sampling).
    Returns (H, W) float64; 1 where a pixel has no event; T = 0 gives 1.
    """
    s_ref = np.zeros((H, W))
    for k in range(t_us.shape[0]):
        if t_us[k] <= t_ref_us:
            s_ref[y[k], x[k]] += inc[k]
    out = np.ones((H, W))
    T = t1_us - t0_us
    if T <= 0.0:
        return out
    s = -s_ref  # E(t0) - E(t_ref)
    last = np.full((H, W), float(t0_us))
    area = np.zeros((H, W))
    for k in range(t_us.shape[0]):
        yy, xx = y[k], x[k]
        tk = min(max(float(t_us[k]), t0_us), t1_us)
        area[yy, xx] += (tk - last[yy, xx]) * _exp(s[yy, xx])
        s[yy, xx] += inc[k]
        last[yy, xx] = tk
    for i in range(H):
        for j in range(W):
            out[i, j] = (area[i, j] + (t1_us - last[i, j]) * _exp(s[i, j])) / T
    return out


@njit(cache=True)
def exposure_levels(t_us, x, y, sign, t0_us, t1_us, t_ref_us, H, W):
    """:func:`exposure_mean_exp` for events of one threshold (``sign`` +1 ON,
    -1 OFF, each step theta), once for every theta: per pixel with an event,
    how long over [t0, t1] its count n(tau) - n(t_ref) stays at each level.

    Returns (pix, level, dur_us): pixel index (row * W + column), level
    (int64) and duration (float64 us) of each stretch of positive length, so
    that the mean over the exposure of exp(theta (n(tau) - n(t_ref))) is
    sum(dur_us * exp(theta * level)) / (t1 - t0) over a pixel's stretches
    (:func:`mean_exp_levels`), and 1 for a pixel without one.
    """
    n = t_us.shape[0]
    level = np.zeros(H * W, np.int64)
    for k in range(n):
        if t_us[k] <= t_ref_us:
            level[y[k] * W + x[k]] -= sign[k]  # count(t0) - count(t_ref)
    last = np.full(H * W, np.nan)  # nan: no event yet
    o_pix = np.empty(2 * n, np.int64)
    o_lvl = np.empty(2 * n, np.int64)
    o_dur = np.empty(2 * n)
    m = 0
    for k in range(n):
        p = y[k] * W + x[k]
        tk = min(max(float(t_us[k]), t0_us), t1_us)
        t_prev = t0_us if math.isnan(last[p]) else last[p]
        if tk > t_prev:
            o_pix[m], o_lvl[m], o_dur[m] = p, level[p], tk - t_prev
            m += 1
        level[p] += sign[k]
        last[p] = tk
    for k in range(n):  # the stretch after each pixel's last event, once
        p = y[k] * W + x[k]
        if not math.isnan(last[p]):
            if t1_us > last[p]:
                o_pix[m], o_lvl[m], o_dur[m] = p, level[p], t1_us - last[p]
                m += 1
            last[p] = np.nan
    return o_pix[:m], o_lvl[:m], o_dur[:m]


@njit(cache=True)
def mean_exp_levels(pix, level, dur_us, theta, T_us, H, W):
    """(H, W) mean over an exposure of length ``T_us`` of exp(theta (n(tau) -
    n(t_ref))) from :func:`exposure_levels`' stretches; 1 where a pixel has none."""
    area = np.zeros(H * W)
    touched = np.zeros(H * W, np.bool_)
    for k in range(pix.shape[0]):
        area[pix[k]] += dur_us[k] * _exp(theta * level[k])
        touched[pix[k]] = True
    out = np.ones(H * W)
    for p in range(H * W):
        if touched[p]:
            out[p] = area[p] / T_us
    return out.reshape(H, W)


@njit(cache=True)
def filter_events(t_us, x, y, inc, state, last_us, ref, alpha_per_us):
    """Advance a per-pixel log-intensity filter through events (in place).

    Between a pixel's events its state relaxes towards ``ref`` (the low-pass
    reference of a complementary filter) with rate ``alpha_per_us``; each event
    adds its ``inc``. ``alpha_per_us = 0`` is direct integration.
    state, last_us, ref : (H, W) float64 arrays (state and last_us updated).
    """
    for k in range(t_us.shape[0]):
        yy, xx = y[k], x[k]
        tk = float(t_us[k])
        if alpha_per_us > 0.0:
            d = math.exp(-alpha_per_us * (tk - last_us[yy, xx]))
            state[yy, xx] = ref[yy, xx] + (state[yy, xx] - ref[yy, xx]) * d
        state[yy, xx] += inc[k]
        last_us[yy, xx] = tk
