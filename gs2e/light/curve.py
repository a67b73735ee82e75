"""Illuminance over a run's time: a level, a ramp between two levels, and
periodic flicker, as pure functions of time.

``s(t) = E(t) m(t) / E_ref``: ``E(t)`` the condition's illuminance (lux; a
C1 ramp in log-illuminance between ``lux`` and ``ramp_to_lux``), ``m(t)`` the
flicker's relative intensity (mean 1 over a period), ``E_ref`` the
illuminance the trained radiance stands for (``light.reference_lux``).
"""

from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np

from gs2e.light.settings import Condition

# samples per flicker period the event clock takes, and per ramp
FLICKER_SAMPLES_PER_PERIOD = 32
RAMP_SAMPLES = 64
# quadrature points per flicker period (and per ramp) of an exposure's mean
_QUAD_PER_PERIOD = 64


def flicker(t_s: np.ndarray, hz: float, depth: float, waveform: str) -> np.ndarray:
    """Relative intensity m(t) >= 0 of a flickering light, mean 1 over a
    period, percent flicker ``depth`` = (max - min) / (max + min).

    ``sine``: 1 + d sin(2 pi f t). ``square`` (PWM at 50 % duty): 1 + d sgn
    sin(2 pi f t). ``rectified`` (a lamp on full-wave rectified mains, whose
    intensity peaks at f = twice the mains frequency): a + b |sin(pi f t)|
    with (max - min) / (max + min) = d and mean a + 2 b / pi = 1.

    Parameters
    ----------
    t_s : times (s), any shape.
    hz : the light's intensity frequency (Hz); 0 or ``depth`` 0: no flicker.
    """
    t_s = np.asarray(t_s, np.float64)
    if hz <= 0 or depth <= 0:
        return np.ones_like(t_s)
    if waveform == "sine":
        return 1.0 + depth * np.sin(2 * math.pi * hz * t_s)
    if waveform == "square":
        return 1.0 + depth * np.where(np.sin(2 * math.pi * hz * t_s) >= 0, 1.0, -1.0)
    a, b = _rectified(depth)
    return a + b * np.abs(np.sin(math.pi * hz * t_s))


def _rectified(depth: float) -> tuple[float, float]:
    """(a, b) of the rectified wave a + b |sin(pi f t)|: min a, max a + b,
    b / (2a + b) = depth and mean a + 2 b / pi = 1."""
    b = 1.0 / ((1.0 - depth) / (2.0 * depth) + 2.0 / math.pi)
    return b * (1.0 - depth) / (2.0 * depth), b


def smoothstep(x: np.ndarray) -> np.ndarray:
    """3x^2 - 2x^3 on [0, 1], 0 before and 1 after (C1)."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


class LightCurve:
    """The light of one run: :meth:`scale` s(t) over [t0_us, t1_us].

    Parameters
    ----------
    condition : the resolved condition.
    t0_us, t1_us : the run's time span (us); ramp times are fractions of it.
    """

    def __init__(self, condition: Condition, t0_us: float, t1_us: float):
        self.condition = c = condition
        self.t0_us, self.t1_us = float(t0_us), float(t1_us)
        span = max(self.t1_us - self.t0_us, 1.0)
        self.ramp = c.ramp_to_lux is not None and c.ramp_to_lux != c.lux
        self.ramp_a_us = self.t0_us + c.ramp_start * span
        self.ramp_b_us = self.ramp_a_us + c.ramp_duration * span
        self.flickers = c.flicker_hz > 0 and c.flicker_depth > 0

    @property
    def constant(self) -> bool:
        """True when s(t) does not change over the run."""
        return not (self.ramp or self.flickers)

    def lux(self, t_us) -> np.ndarray:
        """Illuminance E(t) m(t) (lux-equivalents) at times ``t_us`` (any shape)."""
        c = self.condition
        t = np.asarray(t_us, np.float64)
        e = self._ramped(t)
        if self.flickers:
            e = e * flicker((t - self.t0_us) * 1e-6, c.flicker_hz, c.flicker_depth, c.flicker_waveform)
        return e

    def _ramped(self, t: np.ndarray) -> np.ndarray:
        """E(t): the illuminance before the flicker (lux-equivalents)."""
        c = self.condition
        e = np.full(t.shape, c.lux)
        if self.ramp:
            if self.ramp_b_us > self.ramp_a_us:
                x = smoothstep((t - self.ramp_a_us) / (self.ramp_b_us - self.ramp_a_us))
            else:  # a step
                x = (t >= self.ramp_a_us).astype(np.float64)
            e = np.where(x <= 0, c.lux, np.where(x >= 1, c.ramp_to_lux,  # exact on the plateaus
                                                 c.lux * (c.ramp_to_lux / c.lux) ** x))
        return e

    def scale(self, t_us) -> np.ndarray:
        """s(t) = E(t) m(t) / reference_lux: the factor on the trained linear radiance."""
        return self.lux(t_us) / self.condition.reference_lux

    def rate(self, t_us) -> np.ndarray:
        """d s / d t (per us) at times ``t_us`` (any shape), from the formulas
        of :meth:`lux`: exact where s is smooth; a square wave's and a step's
        jumps have no rate (0 on both sides: a derivative across them would
        be the jump over the difference's width), a rectified wave's kinks
        the side that :meth:`lux` takes there."""
        c = self.condition
        t = np.asarray(t_us, np.float64)
        e, de = self._ramped(t), np.zeros(t.shape)
        if self.ramp and self.ramp_b_us > self.ramp_a_us:  # E = lux ratio^smoothstep(u)
            w = self.ramp_b_us - self.ramp_a_us
            u = (t - self.ramp_a_us) / w
            de = np.where((u > 0) & (u < 1), e * math.log(c.ramp_to_lux / c.lux) * 6.0 * u * (1.0 - u) / w,
                          0.0)
        m, dm = np.ones(t.shape), np.zeros(t.shape)
        if self.flickers:
            hz, d, ts = c.flicker_hz, c.flicker_depth, (t - self.t0_us) * 1e-6
            m = flicker(ts, hz, d, c.flicker_waveform)
            if c.flicker_waveform == "sine":
                dm = d * 2 * math.pi * hz * np.cos(2 * math.pi * hz * ts) * 1e-6
            elif c.flicker_waveform == "rectified":
                sign = np.where(np.sin(math.pi * hz * ts) >= 0, 1.0, -1.0)
                dm = _rectified(d)[1] * sign * math.pi * hz * np.cos(math.pi * hz * ts) * 1e-6
        return (de * m + e * dm) / c.reference_lux

    def max_scale(self) -> float:
        """An upper bound of s(t) over the run."""
        c = self.condition
        top = max(c.lux, c.ramp_to_lux or c.lux)
        m = 1.0
        if self.flickers:
            m = float(flicker(np.linspace(0, 1 / c.flicker_hz, 4097), c.flicker_hz, c.flicker_depth,
                              c.flicker_waveform).max())
        return top * m / c.reference_lux

    def mean_scale(self, ta_us: float, tb_us: float) -> float:
        """Mean of s(t) over [ta, tb] (us): the light an exposure collects
        (composite Gauss-Legendre, 64 points per flicker period and per ramp)."""
        if tb_us <= ta_us or self.constant:
            return float(self.scale(np.array([0.5 * (ta_us + tb_us)]))[0])
        n = 8
        if self.flickers:
            n = max(n, int(math.ceil((tb_us - ta_us) * 1e-6 * self.condition.flicker_hz * _QUAD_PER_PERIOD)))
        if self.ramp:
            n = max(n, _QUAD_PER_PERIOD)
        # cut at the ramp's ends and the flicker's half periods (a step, a square
        # wave's edges and a rectified wave's kinks: integrate each side apart)
        inner = [c for c in (self.ramp_a_us, self.ramp_b_us) if ta_us < c < tb_us]
        if self.flickers:
            half = 0.5e6 / self.condition.flicker_hz
            k = np.arange(math.floor((ta_us - self.t0_us) / half) + 1, math.ceil((tb_us - self.t0_us) / half))
            inner += (self.t0_us + k * half).tolist()
        cuts = [ta_us] + sorted(c for c in inner if ta_us < c < tb_us) + [tb_us]
        x, w = np.polynomial.legendre.leggauss(4)
        total = 0.0
        for a, b in zip(cuts[:-1], cuts[1:]):
            m = max(1, int(math.ceil(n * (b - a) / (tb_us - ta_us) / 4)))
            edges = np.linspace(a, b, m + 1)
            mid, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
            pts = mid[:, None] + half[:, None] * x[None, :]
            total += float(np.sum(self.scale(pts) * w[None, :] * half[:, None]))
        return total / (tb_us - ta_us)

    def max_step_us(self) -> float | None:
        """Longest sampling step that follows the light: 1/32 of a flicker
        period, 1/64 of a ramp (None: a constant light, or a step's jump,
        which no step resolves)."""
        steps = []
        if self.flickers:
            steps.append(1e6 / (self.condition.flicker_hz * FLICKER_SAMPLES_PER_PERIOD))
        if self.ramp and self.ramp_b_us > self.ramp_a_us:
            steps.append((self.ramp_b_us - self.ramp_a_us) / RAMP_SAMPLES)
        return min(steps) if steps else None

    def describe(self) -> dict:
        """What the outputs record of the light."""
        c = asdict(self.condition)
        return {"condition": c.pop("name"), **c, "scale_max": self.max_scale()}
