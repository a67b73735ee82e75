"""Dataset frames along a trajectory: sharp RGB, motion-blurred RGB, depth,
alpha, and a per-frame record of time, pose and intrinsics."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np

from gs2e.common.atomic import atomic_dir, write_json_atomic
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.common.progress import progress
from gs2e.common.settings import require
from gs2e.io.images import to_u8, write_png
from gs2e.io.nerf import write_transforms
from gs2e.io.scene import Camera, Frame, Scene
from gs2e.common.color import linear_to_srgb, srgb_to_linear
from gs2e.light.curve import LightCurve
from gs2e.light.settings import Condition
from gs2e.render.blur import adaptive_blur, average_srgb, subframe_times_us, subframes_needed
from gs2e.render.camera import AutoExposure, FrameCamera, capture, clean_dn, encode
from gs2e.render.settings import RenderSettings
from gs2e.common.motion import pixel_motion_px
from gs2e.trajectory import fixed_times_us

log = get_logger("gs2e.render")
# Image motion of the Gaussian centres over a blurred frame's exposure, recorded
# per frame; the 99th percentile sets the sub-frame count.
MOTION_PERCENTILES = (50, 90, 99)


def exposure_motion(r, t: float, exposure_us: float, centres: np.ndarray,
                    cfg: RenderSettings) -> tuple[np.ndarray, int]:
    """(the motion percentiles (3,) px of the Gaussian ``centres`` (N, 3) over
    the exposure centred on ``t`` (us), the sub-frames that motion needs) for
    the :class:`gs2e.render.renderer.TrajectoryRenderer` ``r``."""
    ta = max(float(r.t0_us), t - exposure_us / 2)
    tb = min(float(r.t1_us), t + exposure_us / 2)
    # summed over the spans between turns: a back-and-forth path may reverse
    # within the exposure, and its ends alone would hide the way out and back
    spans = r.traj.monotone_spans(ta, tb)
    motion = (sum(pixel_motion_px(centres, r.pose(a), r.pose(b), r.K, r.width, r.height,
                                  MOTION_PERCENTILES) for a, b in zip(spans[:-1], spans[1:]))
              if tb > ta else np.zeros(3))
    return motion, subframes_needed(float(motion[2]), cfg.blur_max_step_px, cfg.blur_max_subframes)


def blurred_frame(r, t: float, exposure_us: float, rgb: np.ndarray, centres: np.ndarray,
                  cfg: RenderSettings) -> tuple[np.ndarray, int, np.ndarray]:
    """The blurred frame centred on ``t`` (us) over ``exposure_us``, from the
    :class:`gs2e.render.renderer.TrajectoryRenderer` ``r`` (``rgb`` its sharp
    (H, W, 3) sRGB image at ``t``; ``centres`` the Gaussian centres (N, 3)
    whose image motion sets the sub-frames). Returns (blur (H, W, 3), the
    sub-frames used, the motion percentiles (3,) px over the exposure)."""
    motion, n_sub = exposure_motion(r, t, exposure_us, centres, cfg)
    if n_sub == 1:
        return rgb, n_sub, motion
    if cfg.blur_tolerance_db is not None:
        blur, n_sub, _ = adaptive_blur(r.rgb_at, t, exposure_us, (r.t0_us, r.t1_us), cfg.blur_tolerance_db,
                                       cfg.blur_max_subframes, known={t: rgb})
        return blur, n_sub, motion
    ts = np.clip(subframe_times_us(t, exposure_us, n_sub), r.t0_us, r.t1_us)
    return average_srgb([r.rgb_at(ts_k) for ts_k in ts]), n_sub, motion


class LitFrames:
    """Frames under a light and through the frame camera (render.camera).

    Per frame: the light scales the trained radiance in linear light; the
    blurred frame is the exposure's mean (the light integrated exactly over
    each of the exposure's slices, whose count the image motion sets, as
    :func:`blurred_frame`'s fixed rule); the camera (``model: sensor``)
    exposes it with its exposure and gain (auto-exposure metering the frame
    it just took), adds noise and quantises it; the sharp frame is the clean
    ground truth at that exposure and gain. An ``ideal`` camera clips the
    lit radiance at 1 (a fixed exposure set for the reference light).
    """

    def __init__(self, r, cfg: RenderSettings, cam: FrameCamera, curve: LightCurve | None,
                 centres: np.ndarray, seed: int):
        self.r, self.cfg, self.cam, self.curve, self.centres = r, cfg, cam, curve, centres
        self.seed = int(seed)
        self.interval_us = 1e6 / cfg.fps
        self.ae = AutoExposure(cam, cfg.exposure_us, self.interval_us)
        self.primed = False

    def _scale(self, ta: float, tb: float) -> float:
        return 1.0 if self.curve is None else self.curve.mean_scale(ta, tb)

    def _blur_linear(self, t: float, E: float, rgb: np.ndarray) -> tuple[np.ndarray, int, np.ndarray]:
        r, cfg = self.r, self.cfg
        ta, tb = max(float(r.t0_us), t - E / 2), min(float(r.t1_us), t + E / 2)
        varying = self.curve is not None and not self.curve.constant
        if not varying:
            blur, n_sub, motion = blurred_frame(r, t, E, rgb, self.centres, cfg)
            return srgb_to_linear(blur, clip=True) * self._scale(ta, tb), n_sub, motion
        motion, n_sub = exposure_motion(r, t, E, self.centres, cfg)
        edges = np.linspace(t - E / 2, t + E / 2, n_sub + 1)
        acc = np.zeros_like(rgb, dtype=np.float64)
        for k, tk in enumerate(np.clip(subframe_times_us(t, E, n_sub), r.t0_us, r.t1_us)):
            img = rgb if n_sub == 1 else r.rgb_at(float(tk))
            a, b = np.clip(edges[k:k + 2], r.t0_us, r.t1_us)
            acc += srgb_to_linear(img, clip=True) * self._scale(float(a), float(b))
        return acc / n_sub, n_sub, motion

    def frame(self, i: int, t: float, rgb: np.ndarray):
        """(sharp sRGB, blurred sRGB or None, sub-frames, motion percentiles,
        the frame table's extra columns) of frame ``i`` at ``t`` (us) from its
        sharp render ``rgb``."""
        cam, cfg = self.cam, self.cfg
        x_sharp = srgb_to_linear(np.asarray(rgb, np.float64), clip=True) * self._scale(t, t)
        if cam.on and not self.primed:
            self.ae.prime(x_sharp)
            self.primed = True
        E = self.ae.exposure_us if cam.on else float(cfg.exposure_us)
        g = self.ae.gain if cam.on else 1.0
        n_sub, motion, blur, sat = 1, np.full(3, np.nan), None, float("nan")
        metered = x_sharp
        if cfg.write_blur:
            x_blur, n_sub, motion = self._blur_linear(t, E, rgb)
            metered = x_blur
            if cam.on:
                dn, full = capture(x_blur, E, g, cam, np.random.default_rng([self.seed, i]))
                blur, sat = encode(dn, cam), float(full.mean())
            else:
                blur, sat = linear_to_srgb(x_blur), float((x_blur >= 1.0).mean())
        sharp = (encode(clean_dn(x_sharp, E, g, cam), cam, black=False) if cam.on else linear_to_srgb(x_sharp))
        if cam.on:
            self.ae.update(self.ae.signal(metered), self.interval_us * 1e-6)
        ta, tb = t - E / 2, t + E / 2
        lux = (self._scale(max(ta, self.r.t0_us), min(tb, self.r.t1_us))
               * (self.curve.condition.reference_lux if self.curve is not None else float("nan")))
        return sharp, blur, n_sub, motion, {"exposure_us": E, "gain": g, "saturated_fraction": sat,
                                            "illuminance_lux": lux}

    def describe(self) -> dict:
        """What render_stats.json records of the light and the camera."""
        from dataclasses import asdict

        return {"light": self.curve.describe() if self.curve is not None else None,
                "camera": asdict(self.cam)}


def render_dataset(model_dir: str | Path, trajectory_path: str | Path, out_dir: str | Path,
                   cfg: RenderSettings, scene_id: str | None = None,
                   sensor: tuple[tuple[int, int], str] | None = None,
                   light: Condition | None = None, seed: int = 0) -> dict[str, Any]:
    """Render the dataset frames of one trajectory into ``out_dir`` (atomic),
    with the ``render`` settings ``cfg`` (checked across keys when they were
    built: :meth:`gs2e.common.settings.Section.defaults`).

    ``sensor``: ((W, H), fit) of the event sensor's camera to render through
    instead of the trajectory's (x render.scale), so frames and events share
    one camera (see :mod:`gs2e.common.camera`).

    Layout: ``rgb/NNNNNN.png`` (sharp, at the frame time), ``blur/NNNNNN.png``
    (average over ``exposure_us`` centred on the same time, in linear light),
    ``depth/NNNNNN.npz`` (float32 expected camera z), ``alpha/NNNNNN.png``,
    ``frames.parquet`` (frame, t_us int64, c2w (16 floats, OpenCV axes), fx, fy,
    cx, cy, width, height, exposure_us, n_subframes, coverage, motion_px_p50 /
    _p90 / _p99 (percentiles over the Gaussian centres in view of their image
    motion over the exposure, px; null without blur)),
    ``transforms.json`` (NeRF convention, OpenGL axes), ``render_stats.json``
    and ``metrics.parquet``.

    ``light``: the run's lighting condition (:mod:`gs2e.light`), which scales
    the trained radiance in linear light over time; with it, or with
    ``render.camera.model: sensor``, frames go through :class:`LitFrames`
    (the frame camera: exposure, gain, noise, saturation; ``seed`` keys its
    noise per frame) and frames.parquet adds ``gain``, ``saturated_fraction``
    (of the blurred frame's pixel values) and ``illuminance_lux`` (mean over
    the exposure). Without both, frames are as they always were.

    A view with less than ``min_coverage`` of its pixels covered by the model
    (alpha > 0.5) is an error naming the trajectory and time: the camera left
    the reconstructed scene.
    """
    import pandas as pd

    from gs2e.metrics.table import write_metrics
    # here, not at the top: readers of the frames table (windows, export, the
    # DataLoader) must not load the renderer (torch, splat) or carry its code version
    from gs2e.render.renderer import TrajectoryRenderer

    cfg = require(cfg, RenderSettings, "render_dataset")
    t_start = time.perf_counter()
    r = TrajectoryRenderer(model_dir, trajectory_path, cfg.background, cfg.scale,
                           cfg.backend, sensor=sensor, order_step_px=cfg.order_step_px)
    if np.any(np.diff(r.traj.t_us) <= 0):
        raise InputError(f"{trajectory_path}: timestamps are not strictly increasing")
    times = fixed_times_us(r.t0_us, r.t1_us, cfg.fps)
    E = float(cfg.exposure_us)
    centres = r.gaussian_centres()
    cam = FrameCamera.from_section(cfg.camera)
    lit = (LitFrames(r, cfg, cam, LightCurve(light, r.t0_us, r.t1_us) if light is not None else None,
                     centres, seed) if light is not None or cam.on else None)
    rows, n_sub_total = [], 0
    with atomic_dir(out_dir) as out:
        subs = ("rgb", "alpha") + (("blur",) if cfg.write_blur else ()) + (("depth",) if cfg.write_depth else ())
        for sub in subs:
            (out / sub).mkdir()
        for i, t in enumerate(progress(times, desc=f"rendering {r.name}")):
            c2w = r.pose(int(t))
            rgb, alpha, depth = r.render_pose(c2w)
            if r.window != "cut":  # the continuous render's image (alpha, depth: this pose's order)
                rgb = r.rgb_at(float(t)).astype(np.float64)
            coverage = float((alpha > 0.5).mean())
            if coverage < cfg.min_coverage:
                raise InputError(f"trajectory {trajectory_path}: the view at t={int(t)} us is empty "
                                 f"({coverage:.1%} of pixels covered < render.min_coverage): "
                                 "the camera left the reconstructed scene")
            name = f"{i:06d}.png"
            extra: dict[str, float] = {}
            if lit is not None:
                rgb, blur, n_sub, motion, extra = lit.frame(i, float(t), rgb)
                E = extra.pop("exposure_us")
            write_png(out / "rgb" / name, to_u8(rgb))
            write_png(out / "alpha" / name, to_u8(alpha)[..., None].repeat(3, axis=2))
            if cfg.write_depth:
                np.savez_compressed(out / "depth" / f"{i:06d}.npz", depth=depth.astype(np.float32))
            if lit is None:
                n_sub, motion = 1, np.full(3, np.nan)
                if cfg.write_blur:
                    blur, n_sub, motion = blurred_frame(r, float(t), E, rgb, centres, cfg)
            if cfg.write_blur:
                write_png(out / "blur" / name, to_u8(blur))
                n_sub_total += n_sub
            rows.append({"frame": i, "file": name, "t_us": int(t), "c2w": c2w.reshape(-1).tolist(),
                         "fx": r.fx, "fy": r.fy, "cx": r.cx, "cy": r.cy, "width": r.width,
                         "height": r.height, "exposure_us": E if cfg.write_blur else 0.0,
                         "n_subframes": n_sub, "coverage": coverage,
                         **{f"motion_px_p{q}": float(m) for q, m in zip(MOTION_PERCENTILES, motion)},
                         **extra})
        df = pd.DataFrame(rows)
        df["t_us"] = df["t_us"].astype("int64")
        df.to_parquet(out / "frames.parquet", index=False)
        cam = Camera(r.fx, r.fy, r.cx, r.cy)
        frames = [Frame(row["file"], cam, np.asarray(row["c2w"]).reshape(4, 4)) for row in rows]
        write_transforms(Scene(r.width, r.height, frames, "render"), out / "transforms.json", image_prefix="rgb/")
        wall = time.perf_counter() - t_start
        stats = {"trajectory": r.name, "n_frames": len(rows), "fps": cfg.fps,
                 "duration_s": (r.t1_us - r.t0_us) / 1e6, "renders": r.renders,
                 "mean_subframes": n_sub_total / max(1, len(rows)) if cfg.write_blur else None,
                 "time_s": wall, "frames_per_s": len(rows) / wall if wall > 0 else None,
                 "renders_per_s": r.renders / wall if wall > 0 else None}
        if lit is not None:
            stats.update(lit.describe())
        write_json_atomic(out / "render_stats.json", stats)
        write_metrics(out / "metrics.parquet", stats, scene_id=scene_id, stage="render")
    log.info("%s: %d frames (%d renders, %.1f sub-frames per blurred frame) in %.1f s",
             r.name, len(rows), r.renders, stats["mean_subframes"] or 1, wall)
    return stats


def read_frames_table(folder: str | Path):
    """frames.parquet with c2w as (N, 4, 4) array column restored."""
    import pandas as pd

    df = pd.read_parquet(Path(folder) / "frames.parquet")
    df["c2w"] = [np.asarray(v, np.float64).reshape(4, 4) for v in df["c2w"]]
    return df
