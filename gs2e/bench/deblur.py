"""Event-based deblurring baselines: EDI (Pan et al., CVPR 2019), model-free.

A blurred frame is the mean of the latent image over its exposure
[t0, t1]; events say how the log intensity changed meanwhile:
log(L(tau) + eps) = log(L(t_ref) + eps) + E(tau) - E(t_ref), E the running
sum of signed log steps (+theta_on per ON, -theta_off per OFF event). Hence

    B + eps = (L(t_ref) + eps) * mean over the exposure of exp(E(tau) - E(t_ref))

and the latent frame at t_ref is (B + eps) / m - eps, m that mean (the
"double integral"). gs2e works on linear light (the blur is a linear-light
average, the event models see linear luminance); colour is restored by
ratio: every linear channel is divided by the same m.

Images are (H, W, 3) float arrays, sRGB-encoded in [0, 1] (as the PNG
frames); thresholds are log-intensity steps, (H, W) maps or scalars.
"""

from __future__ import annotations

import math

import numpy as np

from gs2e.bench import _kernels as K
from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear

# Threshold search of the no-oracle variant: a geometric grid, then a
# golden-section refinement around its best point.
GOLDEN = (math.sqrt(5) - 1) / 2


def log_steps(p: np.ndarray, x: np.ndarray, y: np.ndarray, theta_on, theta_off) -> np.ndarray:
    """Signed log-intensity step of each event: +theta_on (p = 1), -theta_off
    (p = 0); thresholds scalars or (H, W) maps indexed at the event's pixel."""
    on = np.asarray(theta_on, np.float64)
    off = np.asarray(theta_off, np.float64)
    up = on[y, x] if on.ndim == 2 else np.full(len(p), float(on))
    down = off[y, x] if off.ndim == 2 else np.full(len(p), float(off))
    return np.where(np.asarray(p) > 0, up, -down)


def exposure_mean_exp(t_us, x, y, steps, t0_us: float, t1_us: float, t_ref_us: float,
                      shape: tuple[int, int]) -> np.ndarray:
    """(H, W) mean over [t0, t1] of exp(E(tau) - E(t_ref)) (see module
    docstring), exact for the event signal; 1 where no event fired."""
    H, W = shape
    return K.exposure_mean_exp(np.asarray(t_us, np.float64), np.asarray(x, np.int64),
                               np.asarray(y, np.int64), np.asarray(steps, np.float64),
                               float(t0_us), float(t1_us), float(t_ref_us), int(H), int(W))


def edi_latent(blur_srgb: np.ndarray, mean_exp: np.ndarray, log_eps: float) -> np.ndarray:
    """The latent frame (H, W, 3, sRGB in [0, 1]) of a blurred frame given the
    exposure's double integral ``mean_exp`` (H, W); clipped to [0, 1]."""
    lin = srgb_to_linear(np.clip(blur_srgb, 0.0, 1.0))
    lat = (lin + log_eps) / mean_exp[..., None] - log_eps
    return linear_to_srgb(np.clip(lat, 0.0, 1.0))


def choose_theta(blur_a: np.ndarray, blur_b: np.ndarray, t_us, x, y, p, t_a_us: float,
                 t_b_us: float, exposure_us: float, log_eps: float, theta_min: float,
                 theta_max: float, steps: int) -> float:
    """EDI without an oracle: the threshold (ON = OFF) under which two
    consecutive blurred frames agree (the multi-frame criterion of EDI, Pan et
    al.): frame a inverted at its time t_a, and frame b inverted at t_b then
    carried back to t_a by the events between, give the same log luminance.
    The mean squared difference over pixels well exposed in both frames is
    minimised over a geometric grid of ``steps`` values in [theta_min,
    theta_max], then by golden-section search between the best point's
    neighbours. Events: time-sorted, covering both exposures. nan without events
    or well-exposed pixels."""
    shape = blur_a.shape[:2]
    t_us = np.asarray(t_us, np.float64)
    x, y = np.asarray(x, np.int64), np.asarray(y, np.int64)
    unit = log_steps(p, x, y, 1.0, 1.0)
    half = exposure_us / 2
    Ya = luminance(srgb_to_linear(np.clip(blur_a, 0.0, 1.0)))
    Yb = luminance(srgb_to_linear(np.clip(blur_b, 0.0, 1.0)))
    ok = (Ya > 0.01) & (Ya < 0.99) & (Yb > 0.01) & (Yb < 0.99)
    if len(t_us) == 0 or not ok.any():
        return math.nan

    def window(t0: float, t1: float) -> slice:
        return slice(int(np.searchsorted(t_us, t0, "left")), int(np.searchsorted(t_us, t1, "right")))

    wa, wb = window(t_a_us - half, t_a_us + half), window(t_b_us - half, t_b_us + half)
    between = (t_us > t_a_us) & (t_us <= t_b_us)
    dE = np.zeros(shape)  # E(t_b) - E(t_a) per pixel, per unit threshold
    np.add.at(dE, (y[between], x[between]), unit[between])
    # what does not depend on theta, once: each exposure's levels per pixel
    # (K.exposure_levels: a theta costs one exp per stretch, not a pass over
    # the events and the image) and the log of the blurred luminance
    sign = unit.astype(np.int64)
    H, W = shape
    exposures = [(K.exposure_levels(t_us[w], x[w], y[w], sign[w], t - half, t + half, t, H, W),
                  (t + half) - (t - half)) for w, t in ((wa, t_a_us), (wb, t_b_us))]
    log_a, log_b = np.log(Ya[ok] + log_eps), np.log(Yb[ok] + log_eps)
    dE_ok = dE[ok]
    cache: dict[float, float] = {}

    def cost(theta: float) -> float:
        if theta not in cache:
            ma, mb = (K.mean_exp_levels(*lv, theta, T, H, W)[ok] for lv, T in exposures)
            d = (log_a - np.log(ma)) - ((log_b - np.log(mb)) - theta * dE_ok)
            cache[theta] = float(np.mean(d ** 2))
        return cache[theta]

    grid = np.geomspace(theta_min, theta_max, steps)
    costs = [cost(float(g)) for g in grid]
    i = int(np.argmin(costs))
    a, b = math.log(float(grid[max(i - 1, 0)])), math.log(float(grid[min(i + 1, steps - 1)]))
    c, d = b - GOLDEN * (b - a), a + GOLDEN * (b - a)  # golden section on log theta
    for _ in range(6):
        if cost(math.exp(c)) <= cost(math.exp(d)):
            b, d = d, c
            c = b - GOLDEN * (b - a)
        else:
            a, c = c, d
            d = a + GOLDEN * (b - a)
    return min(cache, key=cache.get)
