"""The dataset's bench table: one row per scene x trajectory x task x method.

Columns: scene_id, trajectory (the run: <trajectory>[@<condition>]), light
(the run's lighting condition; only where a run has one), preset, task, model, method, n_frames,
psnr (dB, from the mean MSE over the scored frames: an exact match counts as
zero error, not as a missing value), ssim (mean), motion_px_median /
motion_px_p90 (over frames, of each frame's median image motion over its
exposure), theta_median (EDI's log threshold), time_s_per_frame, and each
task's own columns (its ``summary``, :mod:`gs2e.bench.tasks`): for
video: psnr_at_0_5s (the frame nearest 0.5 s after the keyframe; null if the
trajectory is shorter), psnr_end (its last scored frame), drift_db_per_s
(least-squares slope of per-frame PSNR against time); for recon3d:
psnr is on luminance after the per-image log-affine correction (see
gs2e.bench.recon3d), psnr_raw the same uncorrected, psnr_rgb uncorrected
colour, psnr_rgb_corrected colour corrected per channel (what colour events
teach), cpu_min the variant's training CPU-minutes, n_gaussians its final
count; for flow (psnr and ssim null): aee_px, out_3px, aee_px_events (means
over the scored frame pairs, gs2e.bench.flow_task).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable

import numpy as np

from gs2e.bench.dataset import pooled_psnr
from gs2e.bench.tasks import TASKS

KEYS = ("scene_id", "trajectory", "light", "preset", "task", "model", "method")


def summarise(df) -> list[dict]:
    """Aggregate rows of bench tables (a DataFrame) into summary rows."""
    out = []
    if len(df) == 0:
        return out
    for key, g in df.groupby([k for k in KEYS if k in df.columns], dropna=False, sort=False):
        g = g.sort_values("t_us")
        row = dict(zip([k for k in KEYS if k in df.columns], key))
        mse = g["mse"].to_numpy(np.float64)
        motion = g["motion_px"].to_numpy(np.float64)
        motion = motion[np.isfinite(motion)]
        theta = g["theta"].to_numpy(np.float64)
        theta = theta[np.isfinite(theta)]
        row.update(n_frames=int(len(g)), psnr=pooled_psnr(mse), ssim=float(g["ssim"].mean()),
                   motion_px_median=float(np.median(motion)) if motion.size else math.nan,
                   motion_px_p90=float(np.percentile(motion, 90)) if motion.size else math.nan,
                   theta_median=float(np.median(theta)) if theta.size else math.nan,
                   time_s_per_frame=float(g["time_s"].mean()))
        task = TASKS.get(row.get("task"))  # tables of a task no longer registered: common columns
        fn = task.summariser() if task is not None else None
        if fn is not None:
            fn(g, row)
        out.append(row)
    return out


def write_summary(tables: Iterable[str | Path], out: str | Path) -> list[dict]:
    from gs2e.metrics.table import read_metrics, write_metrics

    tables = list(tables)
    rows = summarise(read_metrics(tables)) if tables else []
    write_metrics(out, rows)
    return rows
