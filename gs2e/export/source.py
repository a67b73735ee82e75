"""One trajectory's products as an exporter reads them: frames, windows,
events, the continuous trajectory and the scene's sparse points."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from gs2e.common.errors import InputError
from gs2e.events.models import Events
from gs2e.export.conventions import check_events_in_sensor, check_polarity01, check_times_us
from gs2e.export.windows import covered_frame_range, read_windows
from gs2e.light.settings import split_run


def windows_path(scene_dir: str | Path, traj: str) -> Path:
    """Where the workflow writes a trajectory's windows table."""
    return Path(scene_dir) / "windows" / f"{traj}.parquet"


@dataclass
class TrajectorySource:
    """Read-only view of ``<scene_dir>/{frames,events,windows,trajectories}`` for
    one trajectory. ``windows_file`` defaults to ``windows/<traj>.parquet``."""

    scene_dir: Path
    traj: str
    windows_file: Path | None = None

    def __post_init__(self) -> None:
        self.scene_dir = Path(self.scene_dir)
        self.frames_dir = self.scene_dir / "frames" / self.traj
        self.events_dir = self.scene_dir / "events" / self.traj
        self.events_file = self.events_dir / "events.h5"
        # a run <trajectory>@<condition> moves along its trajectory's file
        self.trajectory_file = self.scene_dir / "trajectories" / f"{split_run(self.traj)[0]}.npz"
        wpath = Path(self.windows_file) if self.windows_file else windows_path(self.scene_dir, self.traj)
        for p in (self.frames_dir / "frames.parquet", self.events_file, wpath):
            if not p.exists():
                raise InputError(f"{p} does not exist (trajectory '{self.traj}' of {self.scene_dir})")
        from gs2e.render.dataset import read_frames_table

        self.frames: pd.DataFrame = read_frames_table(self.frames_dir)
        self.windows, self.windows_meta = read_windows(wpath)
        if len(self.windows) != len(self.frames) or not np.array_equal(
                self.windows["t_us"].to_numpy(), self.frames["t_us"].to_numpy()):
            raise InputError(f"{wpath}: its frames do not match {self.frames_dir / 'frames.parquet'} "
                             "(stale windows table: rerun gs2e windows)")
        self.width = int(self.frames["width"].iloc[0])
        self.height = int(self.frames["height"].iloc[0])

    # ------------------------------------------------------------------ frames
    def covered_frames(self) -> np.ndarray:
        """Indices of the frames whose consecutive windows the events cover."""
        a, b = covered_frame_range(self.windows, str(self.events_file))
        return np.arange(a, b + 1)

    def c2w(self, frames: np.ndarray) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses (OpenCV axes) of the given frames."""
        return np.stack([self.frames["c2w"].iloc[int(i)] for i in frames])

    def K(self, frame: int = 0) -> np.ndarray:
        """(3, 3) intrinsics (pixels, pixel centres at +0.5) of a frame."""
        r = self.frames.iloc[int(frame)]
        return np.array([[r.fx, 0, r.cx], [0, r.fy, r.cy], [0, 0, 1.0]])

    def image_path(self, kind: str, frame: int) -> Path:
        """``kind`` = rgb (sharp), blur, alpha; raises if the frame lacks it."""
        p = self.frames_dir / kind / str(self.frames["file"].iloc[int(frame)])
        if not p.exists():
            raise InputError(f"{p} does not exist ({kind} frames not rendered? see render.write_blur)")
        return p

    def image(self, kind: str, frame: int) -> np.ndarray:
        """uint8 (H, W, 3) sRGB image."""
        from gs2e.io.images import read_image

        return read_image(self.image_path(kind, frame))

    def depth(self, frame: int) -> np.ndarray:
        """float32 (H, W) expected depth (scene units); InputError if not written."""
        p = self.frames_dir / "depth" / f"{int(frame):06d}.npz"
        if not p.exists():
            raise InputError(f"{p} does not exist (render.write_depth: false?)")
        with np.load(p) as z:
            return z["depth"]

    def alpha(self, frame: int) -> np.ndarray:
        """float32 (H, W) coverage of the model in [0, 1]."""
        return self.image("alpha", frame)[..., 0].astype(np.float32) / 255.0

    # ------------------------------------------------------------------ events
    def events(self, t0_us: int | None = None, t1_us: int | None = None) -> Events:
        """Events with t0 <= t < t1 (absolute us; all if both None), checked
        against the conventions (int64 sorted times, 0/1 polarity, on the sensor)."""
        from gs2e.events.io import read_h5

        rng = None if t0_us is None and t1_us is None else (int(t0_us), int(t1_us))
        ev, _ = read_h5(self.events_file, rng)
        where = str(self.events_file)
        ev = Events(check_times_us(ev.t, where), ev.x, ev.y, check_polarity01(ev.p, where))
        check_events_in_sensor(ev.x, ev.y, self.width, self.height, where)
        return ev

    @property
    def cfa(self) -> str | None:
        """The colour filter the events were simulated under (events.h5's
        metadata ``cfa``, e.g. RGGB; None: luminance events)."""
        from gs2e.events.io import read_h5
        from gs2e.events.settings import read_metadata

        _, attrs = read_h5(self.events_file, (0, 0))
        return read_metadata(attrs, str(self.events_file)).get("cfa")

    def window_counts(self, kind: str, frames: np.ndarray) -> np.ndarray:
        """Event counts (i1 - i0) of the ``inter`` or ``exp`` windows of frames."""
        w = self.windows.iloc[np.asarray(frames, int)]
        return (w[f"{kind}_i1"] - w[f"{kind}_i0"]).to_numpy(np.int64)

    # -------------------------------------------------------------- geometry
    @functools.cached_property
    def trajectory(self):
        """The continuous trajectory (``pose_at(t_us)``)."""
        from gs2e.trajectory.io import load_trajectory

        if not self.trajectory_file.exists():
            raise InputError(f"{self.trajectory_file} does not exist")
        return load_trajectory(self.trajectory_file)

    def poses_at(self, t_us: np.ndarray) -> np.ndarray:
        """(Q, 4, 4) poses at any times inside the trajectory (float us)."""
        return self.trajectory.pose_at(np.asarray(t_us, np.float64))

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        """Sparse points (P, 3) float64 and colours (P, 3) uint8 of the scene's
        SfM stage (same world frame as the poses); empty arrays if it has none."""
        from gs2e.io.scene import read_scene

        sfm = self.scene_dir / "sfm"
        scene = read_scene(sfm) if (sfm / "scene.json").exists() else None
        if scene is None or scene.points_xyz is None:
            return np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
        rgb = scene.points_rgb if scene.points_rgb is not None else np.full((len(scene.points_xyz), 3), 128)
        return np.asarray(scene.points_xyz, np.float64), np.asarray(rgb, np.uint8)

    def depth_range(self, frames: np.ndarray, lo_pct: float = 0.1, hi_pct: float = 99.9) -> np.ndarray:
        """(N, 2) near/far depth per frame: percentiles of the depth over pixels
        the model covers (alpha > 0.5), like LLFF's bounds from COLMAP points."""
        out = np.zeros((len(frames), 2))
        for k, i in enumerate(frames):
            d = self.depth(int(i))
            m = (self.alpha(int(i)) > 0.5) & np.isfinite(d) & (d > 0)
            if not m.any():
                raise InputError(f"{self.frames_dir}: frame {int(i)} has no covered pixel with a depth")
            out[k] = np.percentile(d[m], [lo_pct, hi_pct])
        return out
