"""Video reconstruction from events after one keyframe, model-free.

Both baselines track per-pixel log(L + eps) from a sharp keyframe:

* direct integration: add each event's signed threshold step
  (log L(t) = log L(key) + sum of steps); errors (missed crossings,
  threshold quantisation, noise) accumulate without bound;
* complementary filter (Scheerlinck, Barnes, Mahony, ACCV 2018): the same
  integration plus a first-order pull, at crossover ``alpha`` (rad/s),
  towards the latest frame, here the keyframe (its only frame input): drift
  stays bounded, at the cost of fading motion back to the keyframe.

Output frames are linear luminance (H, W); the benchmark compares them with
the sharp frames' luminance (grey, sRGB-encoded).
"""

from __future__ import annotations

from typing import Iterator

import numpy as np

from gs2e.bench import _kernels as K

# The reference row of the video task (synthetic and real): the keyframe itself,
# held; what reconstruction from the events has to beat.
KEYFRAME_HELD = "keyframe_held"


def reconstruct(key_luminance: np.ndarray, log_eps: float, t_us: np.ndarray, x: np.ndarray,
                y: np.ndarray, steps: np.ndarray, t_key_us: int, query_us: np.ndarray,
                alpha_rad_s: float = 0.0) -> Iterator[np.ndarray]:
    """Yield the (H, W) linear luminance at each of ``query_us`` (increasing,
    >= t_key_us): the keyframe's log luminance advanced by the events with
    t_key < t <= query (time-sorted arrays; ``steps`` from
    :func:`gs2e.bench.deblur.log_steps`)."""
    ref = np.log(np.asarray(key_luminance, np.float64) + log_eps)
    state = ref.copy()
    last = np.full(ref.shape, float(t_key_us))
    alpha_us = float(alpha_rad_s) * 1e-6
    t_us = np.asarray(t_us)
    xi, yi = np.asarray(x, np.int64), np.asarray(y, np.int64)
    st = np.asarray(steps, np.float64)
    i = int(np.searchsorted(t_us, t_key_us, side="right"))
    for q in np.asarray(query_us):
        j = int(np.searchsorted(t_us, q, side="right"))
        K.filter_events(t_us[i:j].astype(np.float64), xi[i:j], yi[i:j], st[i:j], state, last,
                        ref, alpha_us)
        i = j
        if alpha_us > 0:
            now = ref + (state - ref) * np.exp(-alpha_us * (float(q) - last))
        else:
            now = state
        yield np.clip(np.exp(now) - log_eps, 0.0, 1.0)
