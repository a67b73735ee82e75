"""What every benchmark task reads and how it scores: one trajectory's
frames, events and windows table (:class:`Dataset`, :func:`load_dataset`),
checked for what the task declares it needs (:mod:`gs2e.bench.tasks`), and
the shared scoring (:func:`score`: PSNR, SSIM, MSE)."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from gs2e.bench.tasks import get_task
from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear
from gs2e.common.errors import InputError


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
    cfa: str | None = None  # the events' colour filter (events.cfa, e.g. RGGB); None: luminance
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

    def depth(self, i: int) -> np.ndarray:
        """(H, W) float32 expected camera z of frame i (render.write_depth)."""
        with np.load(self.frames_dir / "depth" / f"{int(i):06d}.npz") as z:
            return z["depth"]

    def alpha(self, i: int) -> np.ndarray:
        """(H, W) float32 coverage of frame i in [0, 1]."""
        from gs2e.io.images import read_image

        return read_image(self.frames_dir / "alpha" / str(self.frames["file"].iloc[i]))[..., 0] / np.float32(255)


def load_dataset(task: str, frames_dir: str | Path, events_dir: str | Path,
                 windows_path: str | Path, trajectory_path: str | Path | None = None) -> Dataset:
    """Read and check what ``task`` (a registered name, :mod:`gs2e.bench.tasks`)
    needs; one-line errors naming what is missing."""
    from gs2e.events.io import read_h5
    from gs2e.events.models import log_contrast
    from gs2e.events.settings import read_metadata, read_settings
    from gs2e.export.windows import read_windows
    from gs2e.render.dataset import read_frames_table

    spec = get_task(task)
    frames_dir, events_dir = Path(frames_dir), Path(events_dir)
    try:
        frames = read_frames_table(frames_dir)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{frames_dir / 'frames.parquet'}: cannot read the frames table ({exc})") from exc
    if spec.needs_depth and not (frames_dir / "depth").is_dir():
        raise InputError(f"{frames_dir}: no depth maps (render.write_depth was off); the {task} task "
                         "needs them")
    if spec.needs_blur:
        if not (frames["exposure_us"] > 0).any() or not (frames_dir / "blur").is_dir():
            raise InputError(f"{frames_dir}: no blurred frames (render.write_blur was off); "
                             f"the {task} task needs them")
    windows, meta = read_windows(windows_path)
    if len(windows) != len(frames) or not np.array_equal(windows["t_us"].to_numpy(),
                                                         frames["t_us"].to_numpy()):
        raise InputError(f"{windows_path}: its frames differ from {frames_dir / 'frames.parquet'} "
                         "(a windows table of another run)")
    ev, attrs = read_h5(events_dir / "events.h5")
    ev_cfg = read_settings(attrs, str(events_dir / "events.h5"))
    cfa = read_metadata(attrs, str(events_dir / "events.h5")).get("cfa")
    if cfa is not None and not spec.colour_events:
        raise InputError(f"{events_dir / 'events.h5'}: events under a {cfa} colour filter; the {task} task "
                         "reads luminance events (simulate them without events.cfa, or run recon3d)")
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
    elif spec.needs_trajectory:
        raise InputError(f"bench --task {task} needs --trajectory (poses between frames)")
    return Dataset(frames_dir, frames, windows, (int(meta["sim_start_us"]), int(meta["sim_end_us"])),
                   ev, np.broadcast_to(th_on, shape), np.broadcast_to(th_off, shape), eps,
                   ev_cfg.model, shape, preset, traj, cfa=cfa)


def grey(srgb: np.ndarray) -> np.ndarray:
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


def timed(fn: Callable, *args):
    t0 = time.perf_counter()
    out = fn(*args)
    return out, time.perf_counter() - t0


def slice_events(ev, i0: int, i1: int):
    from gs2e.events.models import Events

    return Events(ev.t[i0:i1], ev.x[i0:i1], ev.y[i0:i1], ev.p[i0:i1])


def intrinsics(frames, i: int) -> np.ndarray:
    r = frames.iloc[i]
    return np.array([[r["fx"], 0, r["cx"]], [0, r["fy"], r["cy"]], [0, 0, 1]], np.float64)


def motion_px(row) -> float:
    v = row.get("motion_px_p50", math.nan)
    return float(v) if v is not None else math.nan


def pooled_psnr(mse: np.ndarray) -> float:
    """PSNR (dB) of the mean of ``mse`` (inf for a mean of 0)."""
    m = float(np.mean(mse))
    return math.inf if m == 0 else -10.0 * math.log10(m)
