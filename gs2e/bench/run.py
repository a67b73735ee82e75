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

What each task computes is its own module's (:mod:`gs2e.bench.tasks` lists
them: deblur_task, video_task, recon3d); this module only reads, dispatches
and writes.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gs2e.bench import methods as M
from gs2e.bench.dataset import load_dataset
from gs2e.bench.tasks import get_task
from gs2e.common.log import get_logger
from gs2e.light.settings import split_run
from gs2e.io.images import to_u8

log = get_logger("gs2e.bench")


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
    video_learned: tuple[str, ...] = ()  # gs2e.bench.learned.VARIANTS
    flow_max_pairs: int | None = None


def resolve(cfg: dict, seed: int = 0) -> BenchConfig:
    from gs2e.bench.recon3d import recon3d_settings

    r3 = recon3d_settings(cfg, seed)
    return BenchConfig(tuple(cfg["methods"]), int(cfg["eval_every"]),
                       M.DeblurSettings(float(cfg["edi_theta_min"]), float(cfg["edi_theta_max"]),
                                        int(cfg["edi_theta_steps"])),
                       int(cfg["video_keyframe"]), float(cfg["video_cf_alpha_rad_s"]),
                       int(cfg["example_crop_px"]), r3, tuple(cfg["video_learned"]),
                       None if cfg["flow_max_pairs"] is None else int(cfg["flow_max_pairs"]))


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
    rows, shown, example = get_task(task).runner()(ds, cfg, user)
    name = trajectory or (Path(trajectory_path).stem if trajectory_path else Path(frames_dir).name)
    light = split_run(name)[1]  # a run under a lighting condition: its own rows
    write_metrics(out_parquet, rows, scene_id=scene_id, trajectory=name, preset=ds.preset,
                  task=task, model=ds.model, **({"light": light} if light else {}))
    png = (example_strip(shown, cfg.crop_px, f"{name} frame {example}") if rows
           else note_strip(f"{name}: no frame to score"))
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


def note_strip(text: str) -> np.ndarray:
    """A small image that says why a task shows no example (uint8 RGB)."""
    import cv2

    img = np.zeros((24, 8 * len(text) + 8, 3), np.uint8)
    cv2.putText(img, text, (4, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
    return img


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
