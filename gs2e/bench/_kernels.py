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
