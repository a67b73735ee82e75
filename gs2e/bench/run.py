"""The benchmark's I/O edge: one task on one trajectory of a dataset.

Reads the trajectory's frames (``frames/<traj>``), events (``events/<traj>``)
and windows table, runs the task's methods frame by frame and writes one row
per method x frame (``bench/<task>/<traj>.parquet``) and a strip of example
crops (``bench/<task>/<traj>.png``).

Columns: scene_id, trajectory, preset, task, method, frame, t_us, t_rel_s
(deblur: since the first frame; video: since the keyframe), motion_px (the
frame's median image motion over its exposure, from the frames table),
n_events (the window's), psnr (dB; null for an exact match), ssim, mse,
psnr_grey / mse_grey (deblur: the same on luminance, which events measure;
colour restored by ratio cannot follow a change of hue at equal luminance),
theta (the log threshold EDI used: the oracle map's median, or the chosen
one), time_s (the method's wall time on that frame).

Deblurring is scored in sRGB colour against the sharp frame at the same
time; video reconstruction on grey (luminance, sRGB-encoded), since events
carry no colour. Frames whose exposure the trajectory's ends cut short are
not scored (their blur is no plain mean over the exposure), nor frames whose
window the events do not cover.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from gs2e.bench import methods as M
from gs2e.bench.video import reconstruct
from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.common.progress import progress
from gs2e.io.images import to_u8

log = get_logger("gs2e.bench")

TASKS = ("deblur", "video", "recon3d")


@dataclass(frozen=True)
class BenchConfig:
    """The resolved ``bench`` section."""

    methods: tuple[str, ...]
    eval_every: int
    deblur: M.DeblurSettings
    video_keyframe: int
    video_cf_alpha_rad_s: float
    crop_px: int
    recon3d: "object" = None  # gs2e.bench.recon3d.Recon3dSettings


def resolve(cfg: dict, seed: int = 0) -> BenchConfig:
    from gs2e.bench.recon3d import Recon3dSettings

    r3 = Recon3dSettings(
        variants=tuple(cfg["recon3d_variants"]), steps=int(cfg["recon3d_steps"]),
        n_init=int(cfg["recon3d_init_points"]), budget=int(cfg["recon3d_budget"]),
        test_every=int(cfg["recon3d_test_every"]), window_px_max=float(cfg["recon3d_window_px_max"]),
        blur_subframes=int(cfg["recon3d_blur_subframes"]),
        blur_downscale=int(cfg["recon3d_blur_downscale"]), lambda_blur=float(cfg["recon3d_lambda_blur"]),
        resolution_schedule=tuple(tuple(int(v) for v in x) for x in cfg["recon3d_resolution_schedule"]),
        seed=int(seed))
    return BenchConfig(tuple(cfg["methods"]), int(cfg["eval_every"]),
                       M.DeblurSettings(float(cfg["edi_theta_min"]), float(cfg["edi_theta_max"]),
                                        int(cfg["edi_theta_steps"])),
                       int(cfg["video_keyframe"]), float(cfg["video_cf_alpha_rad_s"]),
                       int(cfg["example_crop_px"]), r3)


@dataclass
class Dataset:
    """One trajectory's frames, events and windows, checked for a task."""

    frames_dir: Path
    frames: "object"   # pandas DataFrame (frames.parquet, c2w as (4, 4))
    windows: "object"  # pandas DataFrame (windows table)
    sim_span_us: tuple[int, int]
    events: "object"   # gs2e.events.models.Events
    theta_on: np.ndarray
    theta_off: np.ndarray
    log_eps: float
    model: str
    shape: tuple[int, int]
    preset: str | None
    trajectory: "object" = None  # gs2e.trajectory.Trajectory (recon3d)
    _cache: dict = field(default_factory=dict, repr=False)

    def image(self, kind: str, i: int) -> np.ndarray:
        """Frame i of ``kind`` (rgb, blur) as float sRGB in [0, 1]; the last few
        are kept, since the deblur loop reads each blurred frame as itself, as a
        neighbour and as a partner."""
        from gs2e.io.images import read_image

        key = (kind, i)
        if key not in self._cache:
            if len(self._cache) >= 6:
                self._cache.pop(next(iter(self._cache)))
            img = read_image(self.frames_dir / kind / str(self.frames["file"].iloc[i])) / 255.0
            img.flags.writeable = False  # shared by the methods of a frame (and the next)
            self._cache[key] = img
        return self._cache[key]


def load_dataset(task: str, frames_dir: str | Path, events_dir: str | Path,
                 windows_path: str | Path, trajectory_path: str | Path | None = None) -> Dataset:
    """Read and check what ``task`` needs; one-line errors naming what is missing."""
    from gs2e.events.io import read_h5
    from gs2e.events.presets import log_contrast
    from gs2e.export.windows import read_windows
    from gs2e.render.dataset import read_frames_table

    if task not in TASKS:
        raise InputError(f"unknown bench task '{task}' (choose from {', '.join(TASKS)})")
    frames_dir, events_dir = Path(frames_dir), Path(events_dir)
    try:
        frames = read_frames_table(frames_dir)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{frames_dir / 'frames.parquet'}: cannot read the frames table ({exc})") from exc
    if task == "deblur":
        if not (frames["exposure_us"] > 0).any() or not (frames_dir / "blur").is_dir():
            raise InputError(f"{frames_dir}: no blurred frames (render.write_blur was off); "
                             "the deblur task needs them")
    windows, meta = read_windows(windows_path)
    if len(windows) != len(frames) or not np.array_equal(windows["t_us"].to_numpy(),
                                                         frames["t_us"].to_numpy()):
        raise InputError(f"{windows_path}: its frames differ from {frames_dir / 'frames.parquet'} "
                         "(a windows table of another run)")
    stats_path = events_dir / "stats.json"
    try:
        ev_cfg = json.loads(stats_path.read_text())["metadata"]["config"]
    except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
        raise InputError(f"{stats_path}: cannot read the event model's config ({exc})") from exc
    ev, attrs = read_h5(events_dir / "events.h5")
    if "theta/on" not in attrs:
        raise InputError(f"{events_dir / 'events.h5'}: no per-pixel thresholds (theta/on, theta/off)")
    shape = (int(frames["height"].iloc[0]), int(frames["width"].iloc[0]))
    th_on, th_off, eps = log_contrast(ev_cfg, attrs["theta/on"], attrs["theta/off"])
    if th_on.shape != shape:
        raise InputError(f"{events_dir / 'events.h5'}: sensor {th_on.shape[1]}x{th_on.shape[0]} "
                         f"differs from the frames' {shape[1]}x{shape[0]} ({frames_dir})")
    preset = traj = None
    if trajectory_path is not None:
        from gs2e.trajectory import load_trajectory

        traj = load_trajectory(trajectory_path)
        preset = traj.meta.get("preset")
    elif task == "recon3d":
        raise InputError("bench --task recon3d needs --trajectory (poses between frames)")
    return Dataset(frames_dir, frames, windows, (int(meta["sim_start_us"]), int(meta["sim_end_us"])),
                   ev, np.broadcast_to(th_on, shape), np.broadcast_to(th_off, shape), eps,
                   str(ev_cfg["model"]), shape, preset, traj)


def deblur_frames(ds: Dataset, every: int) -> list[int]:
    """Frames the deblur task scores: a blurred frame whose whole exposure lies
    inside the trajectory and the simulated events."""
    w, f = ds.windows, ds.frames
    E = f["exposure_us"].to_numpy(np.float64)
    t = f["t_us"].to_numpy(np.float64)
    whole = (t - E / 2 >= t[0]) & (t + E / 2 <= t[-1]) & (E > 0)
    ok = whole & w["exp_covered"].to_numpy(bool)
    out = [i for i in np.flatnonzero(ok) if i % every == 0]
    if not out:
        raise InputError(f"{ds.frames_dir}: no blurred frame has its whole exposure inside the "
                         f"simulated events ({ds.sim_span_us[0]}..{ds.sim_span_us[1]} us) and "
                         "the trajectory: nothing to deblur")
    return out


def video_frames(ds: Dataset, key: int, every: int) -> list[int]:
    """Frames after the keyframe up to the end of the simulated events."""
    t = ds.frames["t_us"].to_numpy()
    if not 0 <= key < len(t) - 1:
        raise InputError(f"bench.video_keyframe: frame {key} is not followed by another frame "
                         f"({ds.frames_dir} has {len(t)} frames)")
    s0, s1 = ds.sim_span_us
    if not s0 <= t[key] <= s1:
        raise InputError(f"{ds.frames_dir}: the keyframe {key} (t = {t[key]} us) lies outside the "
                         f"simulated events ({s0}..{s1} us)")
    out = [i for i in range(key + 1, len(t)) if t[i] <= s1 and (i - key) % every == 0]
    if not out:
        raise InputError(f"{ds.frames_dir}: no frame after the keyframe {key} within the "
                         f"simulated events ({s0}..{s1} us)")
    return out


def _grey(srgb: np.ndarray) -> np.ndarray:
    """(H, W, 1) luminance, sRGB-encoded, of an sRGB image (grey passes)."""
    if srgb.ndim == 2:
        return srgb[..., None]
    return linear_to_srgb(luminance(srgb_to_linear(srgb)))[..., None]


def score(img: np.ndarray, ref: np.ndarray) -> dict[str, float]:
    """PSNR (dB; inf for an exact match), SSIM (3DGS's window) and MSE."""
    import torch

    from gs2e.splat.loss import psnr, ssim

    a = torch.tensor(img, dtype=torch.float64)  # a copy: frames are read-only (cached)
    b = torch.tensor(ref, dtype=torch.float64)
    mse = float(((a - b) ** 2).mean())
    return {"psnr": psnr(a, b), "ssim": float(ssim(a, b)), "mse": mse}


def _timed(fn: Callable, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def _slice(ev, i0: int, i1: int):
    from gs2e.events.models import Events

    return Events(ev.t[i0:i1], ev.x[i0:i1], ev.y[i0:i1], ev.p[i0:i1])


def run_deblur(ds: Dataset, cfg: BenchConfig, user: dict[str, Callable]):
    """Rows of the deblur task and the example frame's images per method."""
    rows, f, w = [], ds.frames, ds.windows
    idx = deblur_frames(ds, cfg.eval_every)
    t_first = int(f["t_us"].iloc[0])
    theta_med = float(np.median(np.concatenate([ds.theta_on.ravel(), ds.theta_off.ravel()])))
    example = idx[len(idx) // 2]
    shown: dict[str, np.ndarray] = {}
    K = _intrinsics(f, 0)
    for i in progress(idx, desc="deblur"):
        r = f.iloc[i]
        E = float(r["exposure_us"])
        ev = _slice(ds.events, int(w["exp_i0"].iloc[i]), int(w["exp_i1"].iloc[i]))
        blur = ds.image("blur", i)
        inp = M.BenchInput(
            "deblur", i, int(r["t_us"]), ev, int(w["exp_t0_us"].iloc[i]), int(w["exp_t1_us"].iloc[i]),
            np.asarray(r["c2w"]), K, ds.theta_on, ds.theta_off, ds.log_eps, E, blur,
            ds.image("blur", i - 1) if i > 0 else None,
            ds.image("blur", i + 1) if i + 1 < len(f) else None)
        # EDI integrates over the exact exposure [t - E/2, t + E/2]
        inp = _with_exact_exposure(inp)
        sharp = ds.image("rgb", i)
        outs: dict[str, tuple[np.ndarray, float, float]] = {}
        img, dt = _timed(M.blurred, inp)
        outs["blurred"] = (img, math.nan, dt)
        img, dt = _timed(M.edi_oracle, inp)
        outs["edi_oracle"] = (img, theta_med, dt)
        j = _partner(i, idx)
        span = None
        if j is not None:
            lo, hi = sorted((float(f["t_us"].iloc[i]), float(f["t_us"].iloc[j])))
            span = _slice(ds.events, int(np.searchsorted(ds.events.t, lo - E / 2, "left")),
                          int(np.searchsorted(ds.events.t, hi + E / 2, "right")))
        (img, th), dt = _timed(M.edi_chosen, inp, cfg.deblur,
                               None if j is None else ds.image("blur", j),
                               None if j is None else int(f["t_us"].iloc[j]), span)
        outs["edi_chosen"] = (img, th, dt)
        for name, fn in user.items():
            img, dt = _timed(fn, inp)
            outs[name] = (M.as_srgb01(img, ds.shape, f"method {name}"), math.nan, dt)
        for name, (img, th, dt) in outs.items():
            img = img if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)
            grey = score(_grey(img), _grey(sharp))
            rows.append({"method": name, "frame": i, "t_us": int(r["t_us"]),
                         "t_rel_s": (int(r["t_us"]) - t_first) * 1e-6,
                         "motion_px": _motion(r), "n_events": len(ev), **score(img, sharp),
                         "psnr_grey": grey["psnr"], "mse_grey": grey["mse"],
                         "theta": th, "time_s": dt})
            if i == example:
                shown[name] = img
        if i == example:
            shown["sharp"] = sharp
    return rows, shown, example


def run_video(ds: Dataset, cfg: BenchConfig, user: dict[str, Callable]):
    """Rows of the video task and the last scored frame's images per method."""
    from gs2e.bench.deblur import log_steps

    f, ev = ds.frames, ds.events
    key = cfg.video_keyframe
    idx = video_frames(ds, key, cfg.eval_every)
    t_key = int(f["t_us"].iloc[key])
    keyframe = ds.image("rgb", key)
    key_lum = luminance(srgb_to_linear(keyframe))
    steps = log_steps(ev.p, ev.x, ev.y, ds.theta_on, ds.theta_off)
    q = f["t_us"].to_numpy()[idx]
    gens = {"integrate": reconstruct(key_lum, ds.log_eps, ev.t, ev.x, ev.y, steps, t_key, q, 0.0),
            "complementary": reconstruct(key_lum, ds.log_eps, ev.t, ev.x, ev.y, steps, t_key, q,
                                         cfg.video_cf_alpha_rad_s)}
    i_key = int(np.searchsorted(ev.t, t_key, side="right"))
    K = _intrinsics(f, 0)
    rows, shown = [], {}
    for i in progress(idx, desc="video"):
        r = f.iloc[i]
        t = int(r["t_us"])
        i1 = int(np.searchsorted(ev.t, t, side="right"))
        target = _grey(ds.image("rgb", i))
        outs = {}
        for name, g in gens.items():
            lum, dt = _timed(next, g)
            outs[name] = (linear_to_srgb(lum)[..., None], dt)
        if user:
            inp = M.BenchInput("video", i, t, _slice(ev, i_key, i1), t_key, t, np.asarray(r["c2w"]),
                               K, ds.theta_on, ds.theta_off, ds.log_eps,
                               float(r["exposure_us"]), keyframe=keyframe, keyframe_t_us=t_key)
            for name, fn in user.items():
                img, dt = _timed(fn, inp)
                outs[name] = (_grey(M.as_srgb01(img, ds.shape, f"method {name}")), dt)
        for name, (img, dt) in outs.items():
            rows.append({"method": name, "frame": i, "t_us": t, "t_rel_s": (t - t_key) * 1e-6,
                         "motion_px": _motion(r), "n_events": i1 - i_key, **score(img, target),
                         "theta": math.nan, "time_s": dt})
            if i == idx[-1]:
                shown[name] = img[..., 0]
        if i == idx[-1]:
            shown["sharp"] = target[..., 0]
    return rows, shown, idx[-1]


def recon3d_data(ds: Dataset, settings) -> "object":
    """The trajectory's training data and held-out frames (gs2e.bench.recon3d)."""
    import torch

    from gs2e.bench.deblur import log_steps
    from gs2e.bench.recon3d import Recon3dData, split_frames

    f, ev, traj = ds.frames, ds.events, ds.trajectory
    t = f["t_us"].to_numpy(np.int64)
    E = f["exposure_us"].to_numpy(np.float64)
    lo = max(ds.sim_span_us[0], int(traj.t_us[0]))
    hi = min(ds.sim_span_us[1], int(traj.t_us[-1]))
    has_blur = bool((E > 0).any()) and (ds.frames_dir / "blur").is_dir()
    half = E / 2 if has_blur else np.zeros_like(E)
    usable = [int(i) for i in np.flatnonzero((t - half >= lo) & (t + half <= hi))]
    if len(usable) < 2 or hi - lo <= 0:
        raise InputError(f"{ds.frames_dir}: recon3d needs at least 2 frames inside the simulated "
                         f"events ({ds.sim_span_us[0]}..{ds.sim_span_us[1]} us), found {len(usable)}")
    train, test = split_frames(usable, settings.test_every)
    if not test:
        raise InputError(f"{ds.frames_dir}: recon3d holds out no frame (bench.recon3d_test_every)")
    H, W = ds.shape
    i0, i1 = np.searchsorted(ev.t, [lo, hi], side="right")
    x, y = ev.x[i0:i1].astype(np.int64), ev.y[i0:i1].astype(np.int64)
    steps = log_steps(ev.p[i0:i1], x, y, ds.theta_on, ds.theta_off)
    sharp = {i: torch.from_numpy(np.asarray(ds.image("rgb", i), np.float32)) for i in train + test}
    blurred = ({i: torch.from_numpy(np.asarray(ds.image("blur", i), np.float32)) for i in train}
               if has_blur else {})
    c2w = np.stack([np.asarray(c, np.float64) for c in f["c2w"]])
    motion = np.array([_motion(f.iloc[i]) for i in range(len(f))], np.float64)
    speed = motion[usable] / np.maximum(E[usable], 1.0)  # px per us over each exposure
    speed = speed[np.isfinite(speed) & (speed > 0) & (E[usable] > 0)]
    # without motion figures (no exposure): a window of window_px_max spans ~2 frames
    us_per_px = (1.0 / float(np.median(speed)) if speed.size else
                 2.0 * float(np.median(np.diff(t))) / settings.window_px_max if len(t) > 1
                 else float(hi - lo) / settings.window_px_max)
    return Recon3dData(_intrinsics(f, 0), W, H, traj.pose_at, (lo, hi), us_per_px, ev.t[i0:i1],
                       y * W + x, steps, ds.log_eps, train, test, t, c2w, E, motion, sharp, blurred)


def run_recon3d(ds: Dataset, cfg: BenchConfig, user: dict[str, Callable]):
    """Rows of the recon3d task (one per variant x held-out frame) and the
    middle held-out frame's corrected luminance per variant."""
    from gs2e.bench import recon3d as R3

    if user:
        log.warning("recon3d: user methods (%s) apply to the deblur and video tasks only; not run",
                    ", ".join(user))
    s = cfg.recon3d
    data = recon3d_data(ds, s)
    f = ds.frames
    t_first = int(f["t_us"].iloc[data.train_idx[0] if data.train_idx else 0])
    example = data.test_idx[len(data.test_idx) // 2]
    log.info("recon3d: %d training frames, %d held out, %d events over %.2f s", len(data.train_idx),
             len(data.test_idx), len(data.ev_t), (data.span_us[1] - data.span_us[0]) * 1e-6)
    rows, shown = [], {}
    for variant in s.variants:
        p, st = R3.train_variant(variant, data, s)
        for r in R3.evaluate(p, data, keep=example):
            img = r.pop("render", None)
            i = r["frame"]
            rows.append({"method": variant, **r, "t_rel_s": (r["t_us"] - t_first) * 1e-6,
                         "motion_px": _motion(f.iloc[i]), "n_events": len(data.ev_t), "theta": math.nan,
                         "time_s": st["wall_s"], "cpu_s": st["cpu_s"], "steps": st["steps"],
                         "n_gaussians": st["n_gaussians"], "n_train_frames": len(data.train_idx)})
            if img is not None:
                y = luminance(srgb_to_linear(np.clip(img, 0, 1)))
                shown[variant] = linear_to_srgb(R3.corrected_luminance(
                    y, r["log_gain"], r["log_offset"], data.log_eps))
    shown["sharp"] = _grey(ds.image("rgb", example))[..., 0]
    return rows, shown, example


def _partner(i: int, scored: list[int]) -> int | None:
    """The neighbouring scored frame EDI's threshold search pairs frame i with:
    the next one, else the previous one (both exposures whole and simulated)."""
    ok = set(scored)
    return i + 1 if i + 1 in ok else (i - 1 if i - 1 in ok else None)


def _with_exact_exposure(inp: M.BenchInput) -> M.BenchInput:
    from dataclasses import replace

    half = inp.exposure_us / 2
    return replace(inp, t0_us=inp.t_us - half, t1_us=inp.t_us + half)


def _intrinsics(frames, i: int) -> np.ndarray:
    r = frames.iloc[i]
    return np.array([[r["fx"], 0, r["cx"]], [0, r["fy"], r["cy"]], [0, 0, 1]], np.float64)


def _motion(row) -> float:
    v = row.get("motion_px_p50", math.nan)
    return float(v) if v is not None else math.nan


def run_task(task: str, frames_dir, events_dir, windows_path, trajectory_path, cfg: BenchConfig,
             out_parquet, out_png, scene_id: str | None = None,
             trajectory: str | None = None) -> dict:
    """Run ``task`` on one trajectory and write its table and example strip."""
    from gs2e.common.atomic import atomic_path
    from gs2e.io.images import write_png
    from gs2e.metrics.table import write_metrics

    t0 = time.perf_counter()
    user = {spec: M.load_method(spec) for spec in cfg.methods}  # before any work
    ds = load_dataset(task, frames_dir, events_dir, windows_path, trajectory_path)
    runner = {"deblur": run_deblur, "video": run_video, "recon3d": run_recon3d}[task]
    rows, shown, example = runner(ds, cfg, user)
    name = trajectory or (Path(trajectory_path).stem if trajectory_path else Path(frames_dir).name)
    write_metrics(out_parquet, rows, scene_id=scene_id, trajectory=name, preset=ds.preset,
                  task=task, model=ds.model)
    png = example_strip(shown, cfg.crop_px, f"{name} frame {example}")
    with atomic_path(out_png) as tmp:
        write_png(tmp, png)
    wall = time.perf_counter() - t0
    # (not gs2e.bench.summary: the dataset table's code must not rerun every task)
    summary = {m: -10 * math.log10(max(float(np.mean([r["mse"] for r in rows if r["method"] == m])),
                                       1e-20))
               for m in dict.fromkeys(r["method"] for r in rows)}
    log.info("%s %s: %d frames in %.1f s; PSNR %s", task, name, len({r["frame"] for r in rows}),
             wall, ", ".join(f"{m} {v:.2f} dB" for m, v in summary.items()))
    return {"task": task, "n_frames": len({r["frame"] for r in rows}), "time_s": wall,
            "psnr": summary}


def example_strip(images: dict[str, np.ndarray], crop_px: int, title: str) -> np.ndarray:
    """Crops of the same region side by side (uint8 RGB), labelled: the
    ``crop_px`` square where the sharp frame has the most gradient energy."""
    import cv2

    sharp = images["sharp"]
    g = sharp if sharp.ndim == 2 else sharp.mean(axis=2)
    H, W = g.shape
    c = min(crop_px, H, W)
    gy, gx = np.gradient(g)
    energy = cv2.boxFilter(np.hypot(gx, gy), -1, (c, c), normalize=False,
                           borderType=cv2.BORDER_CONSTANT)
    h2 = c // 2
    inner = energy[h2:H - (c - h2) + 1, h2:W - (c - h2) + 1]
    y0, x0 = np.unravel_index(int(np.argmax(inner)), inner.shape)
    scale = max(1, 160 // c)
    tiles = []
    for name, img in images.items():
        crop = img[y0:y0 + c, x0:x0 + c]
        if crop.ndim == 2:
            crop = np.repeat(crop[..., None], 3, axis=2)
        crop = to_u8(crop)
        crop = cv2.resize(crop, (c * scale, c * scale), interpolation=cv2.INTER_NEAREST)
        label = np.full((18, crop.shape[1], 3), 255, np.uint8)
        cv2.putText(label, name, (2, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
        tiles.append(np.concatenate([crop, label], axis=0))
        tiles.append(np.full((crop.shape[0] + 18, 4, 3), 255, np.uint8))
    strip = np.concatenate(tiles[:-1], axis=1)
    head = np.full((18, strip.shape[1], 3), 255, np.uint8)
    cv2.putText(head, title, (2, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([head, strip], axis=0)
