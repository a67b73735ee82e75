"""Motion blur as a camera sensor makes it: the time average of the image
over the exposure, in linear light."""

from __future__ import annotations

import math
from typing import Callable

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
        lin = srgb_to_linear(f, clip=True)
        acc = lin if acc is None else acc + lin
    return linear_to_srgb(acc / len(frames_srgb))


def _psnr_db(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else -10.0 * math.log10(mse)


def adaptive_blur(render_srgb: Callable[[float], np.ndarray], t_center_us: float, exposure_us: float,
                  t_range_us: tuple[float, float], tolerance_db: float, n_max: int,
                  known: dict[float, np.ndarray] | None = None) -> tuple[np.ndarray, int, int]:
    """The exposure average in linear light by the trapezoid rule, refined until
    it converges.

    The sub-frame times are the n + 1 ends of n equal slices of [t - E/2, t + E/2]
    (clipped to ``t_range_us``, as the fixed rule clips); doubling n keeps every
    time rendered so far and adds the slices' midpoints. From n = 2 (whose middle
    time is the frame's own: pass its image in ``known``), n doubles until the
    blurred frame changes by less than ``tolerance_db`` (PSNR between the sRGB
    frames of n and n / 2 slices) or a doubling would pass ``n_max``. The change
    bounds the error of the coarser frame, and the error halves or better with
    each doubling, so the frame returned is closer than that to the exposure
    integral.

    Parameters
    ----------
    render_srgb : time (us) -> (H, W, 3) sRGB-encoded image in [0, 1].
    t_center_us, exposure_us : the frame's time and exposure (us).
    t_range_us : (t0, t1) the trajectory's time span (us).
    tolerance_db : stop once PSNR(frame_n, frame_n/2) >= this (dB).
    n_max : most slices (>= 2).
    known : images already rendered, by time (us), reused.

    Returns
    -------
    (blurred sRGB image (H, W, 3) float64, distinct times used, slices n).
    """
    if n_max < 2:
        raise ValueError(f"adaptive_blur needs n_max >= 2, got {n_max}")
    t0, t1 = t_range_us
    # every time is used once, but for the trajectory's ends, onto which clipped
    # times fall: keep those (and the known images), not every sub-frame (at HD
    # 65 float64 frames would be 1.4 GB)
    cache = dict(known or {})
    used: set[float] = set()

    def lin(t: float) -> np.ndarray:
        t = float(min(max(t, t0), t1))
        used.add(t)
        img = cache.get(t)
        if img is None:
            img = render_srgb(t)
            if t in (t0, t1):
                cache[t] = img
        return srgb_to_linear(img, clip=True)

    a = t_center_us - exposure_us / 2
    n = 2
    ends = 0.5 * (lin(a) + lin(a + exposure_us))
    inner = lin(t_center_us)  # sum of the interior samples
    cur = linear_to_srgb((ends + inner) / n)
    while 2 * n <= n_max:
        for k in range(n):
            inner = inner + lin(a + (k + 0.5) * exposure_us / n)
        n *= 2
        nxt = linear_to_srgb((ends + inner) / n)
        change = _psnr_db(nxt, cur)
        cur = nxt
        if change >= tolerance_db:
            break
    return cur, len(used), n
