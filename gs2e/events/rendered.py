"""Samples for the event models rendered on demand from a model along a trajectory.

The I/O edge of the workflow's event stage: loads the Gaussian model (gs2e
train output) and the trajectory, renders linear luminance with the
forward-only renderer (:mod:`gs2e.splat.forward`) at the times the sampling
mode asks for (:mod:`gs2e.events.sampling`), and hands the event models
either whole frames (``fixed``, ``adaptive``, ``motion``) or tile batches
(``tile``).
Nothing is stored: memory does not grow with the trajectory's length.

What changes pixels comes from the render stage (``background``, ``scale``,
``backend``); when and how densely to sample is the event stage's own
``events.sampling`` section.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from numba import njit, prange

from gs2e.common.camera import render_camera
from gs2e.common.errors import ConfigError, InputError
from gs2e.common.settings import require
from gs2e.events.models import TileBatch, log_contrast, model_class
from gs2e.events.sensors import get_sensor, resolve_cfa
from gs2e.events.settings import EventSettings
from gs2e.events.sampling import (MODES, SamplerStats, TileSampler, adaptive_samples, cfa_channels,
                                  image_cfa, image_luminance, image_luminance_rate, motion_times)
from gs2e.light.curve import LightCurve
from gs2e.light.settings import Condition
from gs2e.splat.backend import resolve_backend_for
from gs2e.splat.forward import ContinuousRenderer, ForwardRenderer, image_motion_px, order_knots
from gs2e.splat.model import load_model, model_window, render
from gs2e.splat.rasterize import SplatCamera
from gs2e.trajectory import fixed_times_us, load_trajectory

log = logging.getLogger("gs2e.events")

# fixed mode: steps measured for the motion they carry (RenderedSource.step_motion_px)
STEP_MOTION_PROBES = 64
# image motion per step (px) above which a fixed clock's events bunch on its
# sample times (docs/events.md: fixed 2400 fps at strong, 1.1-4.8 px per step)
STEP_MOTION_WARN_PX = 1.0
# events.sampling.slopes: difference - the step of the one-sided difference (us):
# short against any step between renders, long enough that float32 renders
# resolve it (an edge moves ~1e-3 px in it at mild)
SLOPE_DT_US = 2


def bound_log(settings: EventSettings) -> float:
    """The sampling bound in log(L + eps), eps the model's dark floor
    (:func:`sampling_log_eps`): on the per-pixel change between samples
    (modes adaptive, tile: ``sampling.bound_fraction``) or on the estimated
    error of the curve between them (mode curve: ``sampling.error_fraction``),
    times the smallest contrast threshold the config can draw (theta_on /
    theta_off, or the low end of theta_range) as a log-intensity step
    (voltmeter: log(1 + theta / k1), the bright-pixel limit of the voltage
    threshold)."""
    cfg = require(settings, EventSettings, "bound_log")
    theta = min(cfg.theta_on, cfg.theta_off)
    if cfg.theta_sampling != "fixed":
        theta = min(theta, min(cfg.theta_range))
    theta = model_class(cfg.model).sampling_step(cfg, theta)
    sc = cfg.sampling
    return float(sc.error_fraction if sc.mode == "curve" else sc.bound_fraction) * theta


def sampling_log_eps(settings: EventSettings) -> float:
    """The dark floor of the signal the sampling bound applies to: the event
    model's own log signal (:func:`gs2e.events.models.log_contrast`). Ideal:
    log(L + log_eps). DVS-Voltmeter: its voltage drifts at k1 d/dt log(L *
    scale + k2) (mu = k1 dL/dt / (L + k2)), so its signal is log(L + k2 /
    scale), luminance L in [0, 1]: dark pixels, where the ideal model's log
    swings widely, barely move its voltage."""
    return log_contrast(settings)[2]


@njit(cache=True, parallel=True)
def _hermite_luminance(g0, m0, g1, m1, h, s, log_eps, lum_max, out):
    """out = exp(g) - log_eps clamped to [0, lum_max], g the cubic Hermite
    curve through (g0, slope m0) and (g1, slope m1) at s in [0, 1] of a step
    of h us, in one pass over the pixels (as whole-frame numpy, the same sums
    took a dozen passes over float64 frames). The clamp: a cubic through a
    pixel that saturates overshoots past what a render can hold."""
    s2 = s * s
    s3 = s2 * s
    c0, c1 = 2.0 * s3 - 3.0 * s2 + 1.0, (s3 - 2.0 * s2 + s) * h
    c2, c3 = -2.0 * s3 + 3.0 * s2, (s3 - s2) * h
    for i in prange(out.shape[0]):
        for j in range(out.shape[1]):
            g = c0 * g0[i, j] + c1 * m0[i, j] + c2 * g1[i, j] + c3 * m1[i, j]
            out[i, j] = min(max(math.exp(g) - log_eps, 0.0), lum_max)


def _middle_slope(ga, gb, gc, ha: float, hb: float):
    """Slope at the middle of three samples ha and hb apart: the derivative
    of the parabola through them, exact to O(h^2) on uneven steps (where
    Catmull-Rom's (gc - ga) / (ha + hb) is only O(h)); Catmull-Rom's on even ones."""
    return (gc - gb) * (ha / (hb * (ha + hb))) + (gb - ga) * (hb / (ha * (ha + hb)))


def cubic_substeps(frames, substeps: int, log_eps: float, first: tuple, lum_max: float = math.inf):
    """Frames between renders on a cubic: yields (t_us, (H, W) float32
    luminance), ``substeps`` per step between consecutive renders of
    ``frames`` (an iterator of (t_us, luminance) or (t_us, luminance, slope)
    after ``first``, the render at the span's start, which is not yielded),
    the render itself last in each step.

    In g = log(L + log_eps), each step [t_i, t_{i+1}] is the cubic Hermite
    curve through g_i and g_{i+1}. Its slopes are a render's own ``slope``
    ((H, W) float64, dg/dt per us) where given, else from the neighbouring
    renders: the derivative at t_i of the parabola through renders i - 1, i
    and i + 1 (Catmull-Rom, (g_{i+1} - g_{i-1}) / (t_{i+1} - t_{i-1}), where
    steps are even; one-sided at the span's ends). On a signal smooth in
    time the error is O(h^3) with the neighbours' slopes, even or uneven
    steps, and O(h^4) with exact ones, against a line's O(h^2). Points fall at whole
    microseconds (fewer where the step is shorter than ``substeps`` us);
    luminance is clamped to [0, ``lum_max``] (the event source passes the
    largest a render holds: 1, or the light's largest scale), where the cubic
    through a saturating or darkening pixel overshoots; the renders are
    passed on as they are. Reads one render ahead.
    """
    k = int(substeps)
    t_prev, g_prev = None, None

    def parts(item):
        t, lum = item[0], item[1]
        return t, lum, np.log(lum.astype(np.float64) + log_eps), (item[2] if len(item) > 2 else None)

    t0, _, g0, d0 = parts(first)
    it = iter(frames)
    nxt = next(it, None)
    if nxt is None:
        return
    t1, l1, g1, d1 = parts(nxt)
    while True:
        nxt = next(it, None)
        t2, l2, g2, d2 = (None, None, None, None) if nxt is None else parts(nxt)
        h = float(t1 - t0)
        m0 = (d0 if d0 is not None else (g1 - g0) / h if t_prev is None
              else _middle_slope(g_prev, g0, g1, float(t0 - t_prev), h))
        m1 = (d1 if d1 is not None else (g1 - g0) / h if t2 is None
              else _middle_slope(g0, g1, g2, h, float(t2 - t1)))
        done = set()
        for j in range(1, k):
            t = int(round(t0 + h * j / k))
            if t <= t0 or t >= t1 or t in done:
                continue
            done.add(t)
            out = np.empty(g0.shape, np.float32)
            _hermite_luminance(g0, m0, g1, m1, h, (t - t0) / h, log_eps, float(lum_max), out)
            yield t, out
        yield t1, l1  # the render itself
        if t2 is None:
            return
        t_prev, g_prev, t0, g0, d0, t1, l1, g1, d1 = t0, g0, t1, g1, d1, t2, l2, g2, d2


class _GsplatRenderer:
    """Whole-image renders through gsplat (CUDA) behind the forward renderer's
    interface: tile renders render the whole image; candidates come from the
    CPU renderer (projections only)."""

    def __init__(self, params, info, cpu: ForwardRenderer, background):
        self.p, self.sh_degree, self.cpu = params, int(info["sh_degree"]), cpu
        self.bg = torch.tensor(background, dtype=params["means"].dtype)
        for k in ("width", "height", "n_tiles", "tiles_x", "tiles_y"):
            setattr(self, k, getattr(cpu, k))
        self.image = np.zeros((cpu.height, cpu.width, 3), np.float32)

    def render(self, c2w):
        c = self.cpu.cam
        cam = SplatCamera.from_c2w(c2w, c.fx, c.fy, c.cx, c.cy, c.width, c.height)
        with torch.no_grad():
            self.image[:] = render(self.p, cam, self.bg, self.sh_degree, "gsplat")[0].numpy()
        return self.image

    def render_tiles(self, c2w, tiles, cand):
        return self.render(c2w)

    def candidates(self, *args, **kwargs):
        return self.cpu.candidates(*args, **kwargs)  # whatever the CPU renderer takes

    def centres(self, c2w):
        return self.cpu.centres(c2w)


class RenderedSource:
    """Event-model input rendered from ``model_dir`` along ``trajectory_path``
    (or the part ``span_us`` of it, absolute microseconds).

    ``start()`` renders the first frame: (t0_us, (H, W) float32 luminance);
    ``batches()`` then yields, per sampling mode, ``(times, frames)`` pairs
    (fixed / adaptive / motion: whole frames) or :class:`TileBatch` (tile).
    ``luminance`` is the latest luminance image (per tile in tile mode), for
    previews; ``stats`` counts renders and rendered pixel values.
    """

    def __init__(self, model_dir: str | Path, trajectory_path: str | Path,
                 settings: EventSettings,
                 background=(0.0, 0.0, 0.0), scale: float = 1.0, backend: str = "cpu",
                 batch_frames: int = 32, span_us: tuple[int, int] | None = None,
                 order_step_px: float = 2.0, light: "Condition | None" = None):
        settings = require(settings, EventSettings, "RenderedSource")
        sc = settings.sampling
        if sc.mode not in MODES:
            raise ConfigError(f"events.sampling.mode must be one of {MODES}, got {sc.mode!r}")
        self.settings, self.sc = settings, sc
        self.params, self.info = load_model(model_dir)
        self.traj = load_trajectory(trajectory_path)
        self.name = Path(trajectory_path).stem
        K = np.asarray(self.traj.K, np.float64)
        sensor = get_sensor(settings)  # its pixel array; render.scale does not apply then
        self.K, W, H = render_camera(K, self.traj.width, self.traj.height, scale,
                                     (sensor.size, settings.sensor_fit) if sensor else None)
        self.shape = (H, W)
        self.camera = {"K": self.K.tolist(), "width": W, "height": H,
                       "sensor": sensor.name if sensor else None,
                       "sensor_fit": settings.sensor_fit if sensor else None,
                       "trajectory_camera": {"K": K.tolist(), "width": int(self.traj.width),
                                             "height": int(self.traj.height)}}
        self.window = model_window(self.info)
        self.backend = resolve_backend_for(backend, self.window, "render.backend")
        cpu = ForwardRenderer(self.params, int(self.info["sh_degree"]), self.K[0, 0], self.K[1, 1],
                              self.K[0, 2], self.K[1, 2], W, H, background=background,
                              window=self.window)
        self.renderer = (cpu if self.backend == "cpu"
                         else _GsplatRenderer(self.params, self.info, cpu, background))
        self.t0_us, self.t1_us = int(self.traj.t_us[0]), int(self.traj.t_us[-1])
        # the run's light over the whole path (the frames' own), whatever span is simulated
        self.light = LightCurve(light, self.t0_us, self.t1_us) if light is not None else None
        self.lum_max = max(1.0, self.light.max_scale()) if self.light is not None else 1.0
        cfa = resolve_cfa(settings)
        self.cfa = cfa_channels(cfa) if cfa is not None else None
        self.cfa_pattern = cfa
        if sc.mode == "tile" and (self.light is not None or self.cfa is not None):
            raise ConfigError("events.sampling.mode: tile renders tiles apart and takes neither a lighting "
                              "condition nor a colour filter (events.cfa); use fixed, motion or adaptive")
        # continuous in time (smooth window): depth orders held at knots over the whole path
        if not order_step_px > 0:
            raise ConfigError(f"render.order_step_px must be > 0, got {order_step_px}")

        def path_pose(t):  # the whole path's, whatever span this source simulates
            return self.traj.pose_at(np.array([float(t)]))[0]

        self.continuous = (None if self.window == "cut" else ContinuousRenderer(
            cpu, path_pose, order_knots(cpu, path_pose, self.t0_us, self.t1_us, order_step_px),
            self.t1_us))
        if sc.slopes != "neighbours" and self.continuous is None:
            raise ConfigError(f"events.sampling.slopes: {sc.slopes} needs a model continuous in time "
                              f"(splat.window: smooth); {model_dir} was trained with the cut window, "
                              "whose renders jump where a Gaussian crosses its cut-off")
        if self.continuous is None and sc.mode == "curve":
            log.warning("events %s: mode curve on a model of the cut window, whose renders jump "
                        "where a Gaussian crosses its cut-off or two swap depth: the curve's "
                        "bound takes each jump as curvature and shortens the step (train with "
                        "splat.window: smooth)", self.name)
        if self.continuous is not None and settings.sampling.mode == "tile":
            log.warning("events %s: mode tile renders tiles in each render's own depth order; "
                        "only the whole-image modes (fixed, motion, adaptive, curve) render continuous "
                        "in time", self.name)
        if span_us is not None:  # a part of the trajectory only
            if not self.t0_us <= span_us[0] < span_us[1] <= self.t1_us:
                raise InputError(f"trajectory {self.name}: span {span_us} us outside "
                                 f"[{self.t0_us}, {self.t1_us}]")
            self.t0_us, self.t1_us = int(span_us[0]), int(span_us[1])
        clip = settings.max_duration_s
        if clip:
            self.t1_us = min(self.t1_us, self.t0_us + int(round(clip * 1e6)))
        if self.t1_us <= self.t0_us:
            raise InputError(f"trajectory {self.name}: zero duration, nothing to simulate")
        self.bound = bound_log(settings)
        self.log_eps = sampling_log_eps(settings)
        self.batch_frames = int(batch_frames)
        self.stats = SamplerStats()
        self.luminance = np.zeros(self.shape, np.float32)
        self.n_frames = (len(fixed_times_us(self.t0_us, self.t1_us, sc.fixed_fps))
                         if sc.mode == "fixed" else None)
        self._sampler: TileSampler | None = None

    def metadata(self) -> dict:
        """What the outputs record of this source beyond the settings: the
        light and the colour filter, each only when set (runs without them
        keep their bytes)."""
        out = {}
        if self.light is not None:
            out["light"] = self.light.describe()
        if self.cfa_pattern is not None:
            out["cfa"] = self.cfa_pattern
        return out

    @property
    def duration_us(self) -> int:
        return self.t1_us - self.t0_us

    def pose_at(self, t_us: int) -> np.ndarray:
        if not self.t0_us <= t_us <= self.t1_us:
            raise InputError(f"trajectory {self.name}: time {t_us} us outside "
                             f"[{self.t0_us}, {self.t1_us}]")
        return self.traj.pose_at(np.array([float(t_us)]))[0]

    def frame(self, t_us: int, out: np.ndarray | None = None) -> np.ndarray:
        """(H, W) float32 linear luminance of the whole image at ``t_us`` (into
        ``out`` if given)."""
        img = (self.renderer.render(self.pose_at(t_us)) if self.continuous is None
               else self.continuous.render(t_us))
        out = np.empty(self.shape, np.float32) if out is None else out
        if self.cfa is None:
            image_luminance(img, out)
        else:
            image_cfa(img, self.cfa, out)
        if self.light is not None:  # the light scales the radiance, in linear light
            out *= np.float32(self.light.scale(np.array([float(t_us)]))[0])
        self.stats.renders += 1
        self.stats.tiles_rendered += self.renderer.n_tiles
        self.stats.pixel_samples += self.shape[0] * self.shape[1]
        return out

    def start(self) -> tuple[int, np.ndarray]:
        if self.sc.mode == "tile":
            self._sampler = TileSampler(
                self.renderer, self.pose_at, self.t0_us, self.t1_us, self.bound, self.log_eps,
                dt_min_us=int(self.sc.dt_min_us), dt_max_us=int(self.sc.dt_max_us),
                dt_init_us=int(1e6 / self.sc.fixed_fps),
                max_motion_px=self.sc.max_motion_px,
                window_motion_px=float(self.sc.window_motion_px), stats=self.stats)
            self._tiles = iter(self._sampler)
            first = next(self._tiles)  # renders the first frame, yields the first batch
            self._first_batch = first
            self.luminance[:] = self._sampler.lum0
            return self.t0_us, self._sampler.lum0.copy()
        if self.sc.mode == "fixed":
            self._report_step_motion()
        f0 = self.frame(self.t0_us)
        self.stats.accepted += 1
        self.luminance[:] = f0
        return self.t0_us, f0

    def batches(self) -> Iterator:
        mode = self.sc.mode
        if mode == "tile":
            yield from self._tile_batches()
            return
        # frames go straight into one batch buffer, reused: a batch is consumed
        # (copied to tiles) before the next is rendered
        buf = np.empty((self.batch_frames, *self.shape), np.float32)
        if mode == "fixed":
            frames = ((int(t), None)
                      for t in fixed_times_us(self.t0_us, self.t1_us, self.sc.fixed_fps)[1:])
        elif mode == "motion":
            frames = ((t, None) for t in self.motion_clock())
        else:
            frames = self._adaptive_frames()
        if self.sc.substeps > 1:
            first = (self.t0_us, self.luminance.copy())
            if self.sc.slopes != "neighbours":
                first += (self.log_slope(*first),)
            frames = cubic_substeps(self._rendered(frames), self.sc.substeps, self.log_eps, first,
                                    self.lum_max)
        ts = []
        for t, f in frames:
            if f is None:
                self.stats.accepted += 1
                self.frame(t, buf[len(ts)])
            else:
                buf[len(ts)] = f
            ts.append(t)
            if len(ts) == self.batch_frames:
                self.luminance[:] = buf[len(ts) - 1]
                yield np.array(ts, np.int64), buf
                ts = []
        if ts:
            self.luminance[:] = buf[len(ts) - 1]
            yield np.array(ts, np.int64), buf[:len(ts)]

    def _rendered(self, frames) -> Iterator[tuple]:
        """``frames`` ((t, frame or None: render it)) with every frame rendered
        into its own array (:func:`cubic_substeps` holds four), and its
        :meth:`log_slope` with ``events.sampling.slopes`` difference or tangent."""
        for t, f in frames:
            if f is None:
                self.stats.accepted += 1
                f = self.frame(t)
            yield (t, f, self.log_slope(t, f)) if self.sc.slopes != "neighbours" else (t, f)

    def log_slope(self, t_us: int, lum: np.ndarray) -> np.ndarray | None:
        """d/dt log(L + log_eps) at ``t_us`` ((H, W) float64, per us) of
        ``lum`` = :meth:`frame` (t_us). ``events.sampling.slopes: difference``:
        from a second render :data:`SLOPE_DT_US` later (earlier at the span's
        end), a one-sided difference, the derivative up to O(SLOPE_DT_US) on a
        model continuous in time; None on a span shorter than that (the cubic
        then takes the neighbours' slopes). ``tangent``: the exact derivative
        from the tangent pass (:meth:`tangent_log_slope`)."""
        if self.sc.slopes == "tangent":
            return self.tangent_log_slope(t_us)
        dt = (SLOPE_DT_US if t_us + SLOPE_DT_US <= self.t1_us
              else -SLOPE_DT_US if t_us - SLOPE_DT_US >= self.t0_us else 0)
        if not dt:
            return None
        g = np.log(lum.astype(np.float64) + self.log_eps)
        return (np.log(self.frame(t_us + dt).astype(np.float64) + self.log_eps) - g) / dt

    def tangent_log_slope(self, t_us: int) -> np.ndarray:
        """d/dt log(L + log_eps) at ``t_us`` ((H, W) float64, per us) from the
        tangent pass (:meth:`gs2e.splat.forward.ContinuousRenderer.render_tangent`:
        the image's exact derivative, float64), through the luminance (or the
        colour filter's channel) and the light's scale s(t) (its rate:
        :meth:`gs2e.light.curve.LightCurve.rate`, none across a square wave's
        or a step's jump): (dL s + L ds) / (L s + log_eps).
        Counted in ``stats.tangents``, not as a render."""
        img, dimg = self.continuous.render_tangent(float(t_us))
        lum, dlum = np.empty(self.shape), np.empty(self.shape)
        image_luminance_rate(img, dimg, self.cfa if self.cfa is not None else np.zeros((0, 0), np.int64),
                             lum, dlum)
        if self.light is not None:
            t = np.array([float(t_us)])
            sc, dsc = float(self.light.scale(t)[0]), float(self.light.rate(t)[0])
            dlum = dlum * sc + lum * dsc
            lum = lum * sc
        self.stats.tangents += 1
        return dlum / (lum + self.log_eps)

    def step_motion_px(self, step_us: int, n: int = STEP_MOTION_PROBES) -> np.ndarray:
        """Image motion (px, :func:`gs2e.splat.forward.image_motion_px`: the
        largest displacement of a drawn Gaussian's centre, in units of its
        projected scale where that exceeds 1 px) over steps of ``step_us``
        starting at ``n`` times evenly spread over the span: (n,) float64,
        fewer for a span shorter than n steps. Projections only, no render."""
        step_us = int(min(step_us, self.duration_us))
        starts = np.unique(np.linspace(self.t0_us, self.t1_us - step_us, n).round().astype(np.int64))
        r = self.renderer
        return np.array([image_motion_px(r.centres(self.pose_at(int(t))),
                                         r.centres(self.pose_at(int(t) + step_us))) for t in starts])

    def _report_step_motion(self) -> None:
        """Fixed mode: how far the image moves between samples, into the stats
        and the log; a warning where that exceeds STEP_MOTION_WARN_PX."""
        sc = self.sc
        m = self.step_motion_px(int(round(1e6 / sc.fixed_fps)))
        p50, mx = float(np.median(m)), float(m.max())
        self.stats.step_motion_px_p50, self.stats.step_motion_px_max = p50, mx
        log.info("events %s: fixed %g fps moves the image %.3f px per sample (median of %d steps; "
                 "largest %.3f px)", self.name, sc.fixed_fps, p50, len(m), mx)
        if mx > STEP_MOTION_WARN_PX:
            log.warning("events %s: at fixed %g fps the image moves up to %.2f px between samples, "
                        "so events bunch on the sample times; events.sampling: {mode: motion, "
                        "max_motion_px: 0.5} bounds the motion per sample (docs/events.md)",
                        self.name, sc.fixed_fps, mx)

    def _dt_max_us(self) -> int:
        """Longest step of the adaptive and motion clocks: dt_max_us, and no
        longer than a changing light allows (1/32 of a flicker period, 1/64
        of a ramp: :meth:`gs2e.light.curve.LightCurve.max_step_us`)."""
        light_step = self.light.max_step_us() if self.light is not None else None
        dt = int(self.sc.dt_max_us)
        return dt if light_step is None else max(int(self.sc.dt_min_us), min(dt, int(light_step)))

    def _first_step_us(self) -> int:
        """First step of the adaptive and motion clocks: the fixed_fps period,
        within [dt_min_us, dt_max_us]."""
        sc = self.sc
        return int(min(self._dt_max_us(), max(sc.dt_min_us, 1e6 / sc.fixed_fps)))

    def motion_clock(self) -> Iterator[int]:
        """Sample times after t0 of mode ``motion`` (:func:`motion_times`), one
        clock per span between the path's turns (a turn is always sampled: a
        step across it would measure the motion out and back as none)."""
        sc = self.sc
        edges = self.traj.monotone_spans(self.t0_us, self.t1_us).astype(np.int64)
        for a, b in zip(edges[:-1], edges[1:]):
            times = motion_times(lambda t: self.renderer.centres(self.pose_at(t)), image_motion_px,
                                 int(a), int(b), float(sc.max_motion_px),
                                 int(sc.dt_min_us), self._dt_max_us(), self._first_step_us(),
                                 self.stats)
            next(times)
            yield from times

    def _adaptive_frames(self):
        """Modes adaptive and curve: (t_us, luminance) after t0, one clock
        per span between the path's turns (:func:`adaptive_samples`). Mode
        curve bounds the curve's error (:func:`curve_error`), its history and
        step carried across spans, and the image motion where
        ``max_motion_px`` is set; its first step is dt_min_us (unchecked: a
        fixed_fps period moves a fast HD image by pixels)."""
        cache: dict[int, np.ndarray] = {}

        def render_log(t: int) -> np.ndarray:
            lum = self.frame(t)
            cache[t] = lum
            return np.log(lum.astype(np.float64) + self.log_eps)

        sc = self.sc
        dt0 = self._first_step_us()
        first = np.log(self.luminance.astype(np.float64) + self.log_eps)  # start() rendered t0
        curve = sc.mode == "curve"
        degree = (3 if sc.substeps > 1 else 2) if curve else None
        history = deque([(self.t0_us, first)], maxlen=degree) if curve else None
        limit = self._motion_limit if curve and sc.max_motion_px is not None else None
        # one clock per span between the path's turns: a step across a turn would
        # compare two near-identical frames and miss the way out and back
        edges = self.traj.monotone_spans(self.t0_us, self.t1_us).astype(np.int64)
        for a, b in zip(edges[:-1], edges[1:]):
            if curve:  # nothing to estimate the path's first step from: dt_min, then checked
                dt0 = history[-1][0] - history[-2][0] if len(history) > 1 else int(sc.dt_min_us)
            gen = adaptive_samples(render_log, int(a), int(b), self.bound, int(sc.dt_min_us),
                                   self._dt_max_us(), dt0, self.stats, float(sc.outlier_fraction),
                                   first_log=first, degree=degree, limit=limit, history=history)
            next(gen)
            self.stats.accepted -= 1  # start() or the previous span counted its first time
            for t, log_frame in gen:
                first = log_frame
                lum = cache.pop(t)
                for k in [k for k in cache if k < t]:
                    del cache[k]
                yield t, lum

    def _motion_limit(self, t_us: int, step_us: int) -> int:
        """The longest step from ``t_us``, at most ``step_us``, over which no
        drawn Gaussian's projected centre moves more than ``max_motion_px``
        (at least dt_min_us): the motion clock's first step
        (:func:`motion_times`) as a cap on mode curve's steps. Projections only."""
        sc = self.sc
        if step_us <= sc.dt_min_us:
            return step_us
        times = motion_times(lambda t: self.renderer.centres(self.pose_at(t)), image_motion_px,
                             t_us, t_us + step_us, float(sc.max_motion_px), int(sc.dt_min_us),
                             step_us, step_us)
        next(times)
        return next(times) - t_us

    def _tile_batches(self) -> Iterator[TileBatch]:
        b = self._first_batch
        while b is not None:
            self._update_luminance(b)
            yield b
            b = next(self._tiles, None)

    def _update_luminance(self, b: TileBatch) -> None:
        H, W = self.shape
        tx = -(-W // 16)
        last = b.offsets[1:] - 1
        for tile, i in zip(b.tiles, last):
            ty, tx_ = divmod(int(tile), tx)
            y0, x0 = ty * 16, tx_ * 16
            y1, x1 = min(H, y0 + 16), min(W, x0 + 16)
            self.luminance[y0:y1, x0:x1] = b.lum[i, :y1 - y0, :x1 - x0]
