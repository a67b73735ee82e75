"""The dataset's bench table: one row per scene x trajectory x task x method.

Columns: scene_id, trajectory, preset, task, model, method, n_frames,
psnr (dB, from the mean MSE over the scored frames: an exact match counts as
zero error, not as a missing value), ssim (mean), motion_px_median /
motion_px_p90 (over frames, of each frame's median image motion over its
exposure), theta_median (EDI's log threshold), time_s_per_frame, and for
video: psnr_at_0_5s (the frame nearest 0.5 s after the keyframe; null if the
trajectory is shorter), psnr_end (its last scored frame), drift_db_per_s
(least-squares slope of per-frame PSNR against time); for recon3d:
psnr is on luminance after the per-image log-affine correction (see
gs2e.bench.recon3d), psnr_raw the same uncorrected, psnr_rgb uncorrected
colour, cpu_min the variant's training CPU-minutes, n_gaussians its final
count.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Iterable

import numpy as np

KEYS = ("scene_id", "trajectory", "preset", "task", "model", "method")
VIDEO_AT_S = 0.5


def _pooled_psnr(mse: np.ndarray) -> float:
    m = float(np.mean(mse))
    return math.inf if m == 0 else -10.0 * math.log10(m)


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
        row.update(n_frames=int(len(g)), psnr=_pooled_psnr(mse), ssim=float(g["ssim"].mean()),
                   motion_px_median=float(np.median(motion)) if motion.size else math.nan,
                   motion_px_p90=float(np.percentile(motion, 90)) if motion.size else math.nan,
                   theta_median=float(np.median(theta)) if theta.size else math.nan,
                   time_s_per_frame=float(g["time_s"].mean()))
        if row.get("task") == "video":
            t = g["t_rel_s"].to_numpy(np.float64)
            per = -10.0 * np.log10(np.maximum(mse, 1e-20))
            j = int(np.argmin(np.abs(t - VIDEO_AT_S)))
            step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
            row["psnr_at_0_5s"] = float(per[j]) if abs(t[j] - VIDEO_AT_S) <= max(step, 1e-9) else math.nan
            row["psnr_end"] = float(per[-1])
            row["drift_db_per_s"] = float(np.polyfit(t, per, 1)[0]) if len(t) > 2 else math.nan
        if row.get("task") == "recon3d":
            row["psnr_raw"] = _pooled_psnr(g["mse_raw"].to_numpy(np.float64))
            row["psnr_rgb"] = float(-10.0 * np.log10(np.mean(10.0 ** (-g["psnr_rgb"].to_numpy(np.float64)
                                                                         / 10.0))))
            row["cpu_min"] = float(g["cpu_s"].iloc[0]) / 60.0
            row["n_gaussians"] = int(g["n_gaussians"].iloc[0])
        out.append(row)
    return out


def write_summary(tables: Iterable[str | Path], out: str | Path) -> list[dict]:
    from gs2e.metrics.table import read_metrics, write_metrics

    tables = list(tables)
    rows = summarise(read_metrics(tables)) if tables else []
    write_metrics(out, rows)
    return rows
