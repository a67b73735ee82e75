"""Motion blur as a camera sensor makes it: the time average of the image
over the exposure, in linear light."""

from __future__ import annotations

import math

import numpy as np

from gs2e.common.color import linear_to_srgb, srgb_to_linear


def subframe_times_us(t_center_us: float, exposure_us: float, n: int) -> np.ndarray:
    """Midpoints of n equal slices of [t - E/2, t + E/2] (float64 us): the
    midpoint rule for the exposure integral; n = 1 gives the sharp frame."""
    k = np.arange(n, dtype=np.float64)
    return t_center_us - exposure_us / 2 + (k + 0.5) * exposure_us / n


def subframes_needed(motion_px: float, max_step_px: float, n_max: int) -> int:
    """Sub-frames so that consecutive ones move at most ``max_step_px``."""
    if not math.isfinite(motion_px) or motion_px <= 0:
        return 1
    return int(min(n_max, max(1, math.ceil(motion_px / max_step_px))))


def average_srgb(frames_srgb: list[np.ndarray]) -> np.ndarray:
    """Average sRGB-encoded frames in linear light and re-encode (float64)."""
    acc = None
    for f in frames_srgb:
        lin = srgb_to_linear(np.clip(f, 0.0, 1.0))
        acc = lin if acc is None else acc + lin
    return linear_to_srgb(acc / len(frames_srgb))
