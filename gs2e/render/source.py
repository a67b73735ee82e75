"""The frame source the event simulator consumes, rendered on demand.

Implements the gs2e.events frame-source protocol: iterating yields
``(t_us int, frame float32 (H, W) linear luminance in [0, 1])`` with strictly
increasing times; ``shape``, ``n_frames`` (None when adaptive) and ``name``.
Nothing is stored: memory does not grow with the sequence length.
"""

from __future__ import annotations

import math
from typing import Iterator

import numpy as np

from gs2e.common.errors import ConfigError
from gs2e.render.renderer import TrajectoryRenderer
from gs2e.render.sampler import SamplerStats, adaptive_samples


def fixed_times_us(t0_us: int, t1_us: int, fps: float) -> np.ndarray:
    """Times at ``fps`` from t0 to t1 (t1 included), rounded to integer us."""
    n = int(math.floor((t1_us - t0_us) * fps / 1e6 + 1e-9)) + 1
    t = np.round(t0_us + np.arange(n) * 1e6 / fps).astype(np.int64)
    if t[-1] < t1_us:
        t = np.append(t, np.int64(t1_us))
    return t


class RenderedFrameSource:
    """Linear luminance along a trajectory, at a fixed rate or adaptively.

    mode : "adaptive" (see gs2e.render.sampler) or "fixed".
    fps : rate of the fixed mode (the paper: 2400).
    bound_log : adaptive bound on the per-pixel log-intensity change between
        samples (e.g. 0.25 x the contrast threshold).
    log_eps : log(L + log_eps) is the signal the bound applies to.
    dt_min_us, dt_max_us : adaptive step limits.
    outlier_fraction : fraction of the pixels whose changes the adaptive bound
        ignores (the largest ones; 0 = every pixel is bounded).
    """

    def __init__(self, renderer: TrajectoryRenderer, mode: str = "adaptive", fps: float = 2400.0,
                 bound_log: float = 0.25, log_eps: float = 1e-3, dt_min_us: int = 50,
                 dt_max_us: int = 5000, outlier_fraction: float = 0.0):
        if mode not in ("adaptive", "fixed"):
            raise ConfigError(f"render.sampling must be 'adaptive' or 'fixed', got {mode!r}")
        if fps <= 0 or bound_log <= 0 or not 1 <= dt_min_us <= dt_max_us:
            raise ConfigError("render: fps, bound and step limits must be positive with dt_min_us <= dt_max_us")
        if not 0 <= outlier_fraction < 1:
            raise ConfigError(f"render.adaptive_outlier_fraction must be in [0, 1), got {outlier_fraction}")
        self.r = renderer
        self.mode = mode
        self.fps = fps
        self.bound_log = bound_log
        self.log_eps = log_eps
        self.dt_min_us, self.dt_max_us = int(dt_min_us), int(dt_max_us)
        self.outlier_fraction = float(outlier_fraction)
        self.shape = (renderer.height, renderer.width)
        self.name = renderer.name
        self.stats = SamplerStats()
        self.n_frames = (len(fixed_times_us(renderer.t0_us, renderer.t1_us, fps))
                         if mode == "fixed" else None)

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        r = self.r
        if self.mode == "fixed":
            for t in fixed_times_us(r.t0_us, r.t1_us, self.fps):
                self.stats.rendered += 1
                self.stats.accepted += 1
                yield int(t), r.linear_luminance(int(t))
            return
        # the sampler yields log frames; keep the linear ones of the trials it
        # may still accept (at most two: the newest and a rejected one)
        cache: dict[int, np.ndarray] = {}

        def render_log(t: int) -> np.ndarray:
            lum = r.linear_luminance(t)
            cache[t] = lum
            return np.log(lum.astype(np.float64) + self.log_eps)

        dt0 = int(min(self.dt_max_us, max(self.dt_min_us, 1e6 / self.fps)))
        for t, _ in adaptive_samples(render_log, r.t0_us, r.t1_us, self.bound_log, self.dt_min_us,
                                     self.dt_max_us, dt0, self.stats, self.outlier_fraction):
            lum = cache.pop(t)
            for k in [k for k in cache if k < t]:
                del cache[k]
            yield int(t), lum


def source_for_events(model_dir, trajectory_path, render_cfg: dict, events_cfg: dict) -> RenderedFrameSource:
    """The frame source of the workflow's event stage: the adaptive bound is
    ``render.adaptive_bound_fraction`` x the smallest contrast threshold the
    event config can draw (theta_on/theta_off, or the low end of theta_range),
    as a log-intensity step (for the voltmeter model: log(1 + theta / k1)),
    on all pixels but the ``render.adaptive_outlier_fraction`` that change most."""
    theta = min(events_cfg["theta_on"], events_cfg["theta_off"])
    if events_cfg.get("theta_sampling", "fixed") != "fixed":
        theta = min(theta, min(events_cfg["theta_range"]))
    if events_cfg["model"] == "voltmeter":
        # voltage threshold -> the log-intensity step that crosses it (bright-pixel limit)
        from gs2e.events.presets import get_preset

        k = {i + 1: events_cfg.get(f"k{i + 1}") for i in range(6)}
        theta = float(np.log1p(theta / get_preset(events_cfg["preset"], k).k[0]))
    r = TrajectoryRenderer(model_dir, trajectory_path, render_cfg["background"], render_cfg["scale"],
                           render_cfg.get("backend", "cpu"))
    clip = render_cfg.get("events_max_duration_s")
    if clip:
        r.t1_us = min(r.t1_us, r.t0_us + int(round(clip * 1e6)))
    return RenderedFrameSource(r, render_cfg["sampling"], render_cfg["fixed_fps"],
                               render_cfg["adaptive_bound_fraction"] * theta, render_cfg["log_eps"],
                               render_cfg["adaptive_dt_min_us"], render_cfg["adaptive_dt_max_us"],
                               render_cfg["adaptive_outlier_fraction"])
