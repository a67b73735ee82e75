"""Methods the benchmark evaluates: the built-in baselines and a user's own.

A method is a callable ``method(inp: BenchInput) -> image``, called once per
evaluated frame. It returns the frame at ``inp.t_us``: an (H, W, 3) or
(H, W) float array, sRGB-encoded in [0, 1] like the dataset's PNG frames
(uint8 is accepted and divided by 255); for the flow task, the displacement
(H, W, 2) in pixels over [t0_us, t1_us) (+x right, +y down). A user's method is named
``package.module:function`` (``gs2e bench --method``, ``bench.methods``); it
must be importable by the job's interpreter and must not read the sharp frame
it is scored against (it is not given it). Its input arrays are read-only.

What a method receives (:class:`BenchInput`):

========================  =====================================================
task                      ``"deblur"``, ``"video"`` or ``"flow"``
frame, t_us               the frame to reconstruct and its time (int64 us)
events                    :class:`gs2e.events.models.Events` of the window
                          (absolute int64 us, x, y, p 1 = ON / 0 = OFF):
                          deblur: the blurred frame's exposure [t0_us, t1_us);
                          video: from the keyframe, t0_us < t <= t1_us = t_us;
                          flow: between two frames, [t0_us, t1_us), t_us = t0_us
t0_us, t1_us              the window's bounds
blurred                   deblur: (H, W, 3) float32 blurred frame (sRGB [0, 1]);
                          video, flow: None
blurred_prev/_next        deblur: the neighbouring blurred frames (None at the ends)
keyframe, keyframe_t_us   video: the sharp keyframe (H, W, 3) and its time;
                          deblur: None
c2w, K                    (4, 4) camera-to-world (OpenCV axes), (3, 3) intrinsics
theta_on, theta_off       (H, W) float64 log-intensity step of one ON / OFF event
                          (the simulator's own thresholds: an oracle)
log_eps                   the model's dark floor: events see log(L + log_eps),
                          L linear luminance in [0, 1]
exposure_us               the blurred frames' exposure
========================  =====================================================
"""

from __future__ import annotations

import importlib
import math
import re
from dataclasses import dataclass
from typing import Callable

import numpy as np

from gs2e.bench import deblur as D
from gs2e.common.errors import ConfigError
from gs2e.events.models import Events

METHOD_SPEC = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


@dataclass(frozen=True)
class BenchInput:
    """Everything a method may use for one frame (see the module docstring)."""

    task: str
    frame: int
    t_us: int
    events: Events
    t0_us: int
    t1_us: int
    c2w: np.ndarray
    K: np.ndarray
    theta_on: np.ndarray
    theta_off: np.ndarray
    log_eps: float
    exposure_us: float
    blurred: np.ndarray | None = None
    blurred_prev: np.ndarray | None = None
    blurred_next: np.ndarray | None = None
    keyframe: np.ndarray | None = None
    keyframe_t_us: int | None = None


@dataclass(frozen=True)
class DeblurSettings:
    """The no-oracle EDI's threshold search (bench.edi_* keys)."""

    theta_min: float
    theta_max: float
    theta_steps: int


def blurred(inp: BenchInput) -> np.ndarray:
    """The do-nothing baseline: the blurred frame itself."""
    return inp.blurred


def edi_oracle(inp: BenchInput) -> np.ndarray:
    """EDI with the simulator's own thresholds (an oracle)."""
    ev = inp.events
    steps = D.log_steps(ev.p, ev.x, ev.y, inp.theta_on, inp.theta_off)
    m = D.exposure_mean_exp(ev.t, ev.x, ev.y, steps, inp.t0_us, inp.t1_us, inp.t_us,
                            inp.blurred.shape[:2])
    return D.edi_latent(inp.blurred, m, inp.log_eps)


def edi_chosen(inp: BenchInput, settings: DeblurSettings, partner_blurred: np.ndarray | None,
               partner_t_us: int | None, events_span: Events | None) -> tuple[np.ndarray, float]:
    """EDI with one threshold chosen per frame, without the oracle: the one
    under which this blurred frame and a neighbouring one (``partner_*``, its
    time) agree (:func:`gs2e.bench.deblur.choose_theta`); ``events_span`` covers
    both exposures. Without a partner or events: the blurred frame, theta nan."""
    if partner_blurred is None or events_span is None or len(events_span) == 0:
        return inp.blurred, math.nan
    (t_a, b_a), (t_b, b_b) = sorted([(inp.t_us, inp.blurred), (partner_t_us, partner_blurred)],
                                    key=lambda v: v[0])
    ev = events_span
    theta = D.choose_theta(b_a, b_b, ev.t, ev.x, ev.y, ev.p, t_a, t_b, inp.exposure_us,
                           inp.log_eps, settings.theta_min, settings.theta_max,
                           settings.theta_steps)
    if not math.isfinite(theta):
        return inp.blurred, theta
    ex = inp.events
    steps = D.log_steps(ex.p, ex.x, ex.y, theta, theta)
    m = D.exposure_mean_exp(ex.t, ex.x, ex.y, steps, inp.t0_us, inp.t1_us, inp.t_us,
                            inp.blurred.shape[:2])
    return D.edi_latent(inp.blurred, m, inp.log_eps), theta


def load_method(spec: str) -> Callable[[BenchInput], np.ndarray]:
    """The callable named ``package.module:function`` (one-line errors)."""
    if not METHOD_SPEC.match(spec or ""):
        raise ConfigError(f"bench.methods: '{spec}' is not of the form package.module:function")
    mod_name, fn_name = spec.split(":")
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ConfigError(f"bench.methods: cannot import '{mod_name}' for '{spec}' ({exc})") from exc
    fn = getattr(mod, fn_name, None)
    if not callable(fn):
        raise ConfigError(f"bench.methods: '{mod_name}' has no callable '{fn_name}'")
    return fn


def as_srgb01(img, shape: tuple[int, int], where: str) -> np.ndarray:
    """A method's output as float64 sRGB in [0, 1], (H, W, 3) or (H, W)."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        a = a / 255.0
    a = a.astype(np.float64)
    if a.shape[:2] != tuple(shape) or a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] != 3):
        raise ConfigError(f"{where}: returned an image of shape {a.shape}, "
                          f"expected ({shape[0]}, {shape[1]}, 3) or ({shape[0]}, {shape[1]})")
    if not np.isfinite(a).all():
        raise ConfigError(f"{where}: returned non-finite values")
    return np.clip(a, 0.0, 1.0)
