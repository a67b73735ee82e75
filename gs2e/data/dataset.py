"""The window dataset (see :mod:`gs2e.data`)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import pandas as pd
import torch
from torch.utils.data import Dataset, default_collate

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events
from gs2e.events.represent import event_frame, voxel_grid
from gs2e.export.conventions import check_events_in_sensor, check_polarity01, check_times_us, to_tonic
from gs2e.export.windows import read_windows

WINDOWS = {"inter": "inter", "exposure": "exp"}
REPRESENTATIONS = ("voxel", "counts", "raw")
IMAGES = ("rgb", "blur", "depth")


@dataclass
class _Trajectory:
    scene: str
    name: str
    scene_dir: Path
    frames: pd.DataFrame   # frames.parquet (c2w as (4, 4) arrays)
    windows: pd.DataFrame  # windows/<name>.parquet
    n_events: int


def _select(root: Path, selection: pd.DataFrame | None, scenes: Iterable[str] | None,
            trajectories: Iterable[str] | None) -> list[tuple[str, str]]:
    """(scene, trajectory) pairs: the selection's rows, or every windows table
    under ``root`` filtered by ``scenes`` / ``trajectories``."""
    if selection is not None:
        missing = {"scene_id", "trajectory"} - set(selection.columns)
        if missing:
            raise InputError(f"selection lacks the summary.parquet columns {sorted(missing)}")
        pairs = [(str(s), str(t)) for s, t in zip(selection["scene_id"], selection["trajectory"])]
    else:
        pairs = sorted((p.parent.parent.name, p.stem) for p in root.glob("*/windows/*.parquet"))
    if scenes is not None:
        pairs = [p for p in pairs if p[0] in set(scenes)]
    if trajectories is not None:
        pairs = [p for p in pairs if p[1] in set(trajectories)]
    return list(dict.fromkeys(pairs))


class EventWindowDataset(Dataset):
    """Frame windows of a gs2e results tree as training samples.

    Parameters
    ----------
    root : results folder (``results/``, holding ``<scene>/frames``, ``events``,
        ``windows``).
    selection : optional rows of ``summary.parquet`` (columns ``scene_id``,
        ``trajectory``) to use instead of every trajectory under ``root``.
    scenes, trajectories : optional filters by name.
    window : ``"inter"`` = events between the previous frame and this one
        ([t_prev, t) us); ``"exposure"`` = events over the blurred frame's
        exposure. Windows the simulation did not cover are left out.
    representation : ``"voxel"`` = (n_bins, H, W) float32 voxel grid (+1 ON,
        -1 OFF, linear in time over the window); ``"counts"`` = (2, H, W) int32
        (OFF, ON); ``"raw"`` = tonic-style structured array (x, y, t int64 us,
        p 0/1) of variable length (use :func:`collate_windows`).
    n_bins : voxel grid bins.
    load : which images to load per item: ``rgb`` (sharp, (3, H, W) float32 in
        [0, 1]), ``blur`` (motion-blurred, same), ``depth`` ((1, H, W) float32,
        scene units).

    Items are dicts: ``scene``, ``trajectory``, ``frame``, ``t0_us``, ``t1_us``,
    ``n_events``, ``events``, the loaded images, ``c2w`` ((4, 4) float64,
    camera-to-world, OpenCV axes) and ``K`` ((3, 3) float64, pixels, pixel
    centres at +0.5).
    """

    def __init__(self, root: str | Path, selection: pd.DataFrame | None = None,
                 scenes: Iterable[str] | None = None, trajectories: Iterable[str] | None = None,
                 window: str = "inter", representation: str = "voxel", n_bins: int = 5,
                 load: Sequence[str] = ("rgb", "blur", "depth")):
        from gs2e.render.dataset import read_frames_table

        if window not in WINDOWS:
            raise ConfigError(f"window must be one of {sorted(WINDOWS)}, got {window!r}")
        if representation not in REPRESENTATIONS:
            raise ConfigError(f"representation must be one of {REPRESENTATIONS}, got {representation!r}")
        if not (isinstance(n_bins, int) and n_bins >= 1):
            raise ConfigError(f"n_bins must be a positive integer, got {n_bins!r}")
        bad = set(load) - set(IMAGES)
        if bad:
            raise ConfigError(f"load: unknown images {sorted(bad)} (choose from {IMAGES})")
        self.root, self.window, self.kind = Path(root), window, WINDOWS[window]
        self.representation, self.n_bins, self.load = representation, n_bins, tuple(load)
        self.trajectories: list[_Trajectory] = []
        items = []
        for scene, name in _select(self.root, selection, scenes, trajectories):
            scene_dir = self.root / scene
            wfile = scene_dir / "windows" / f"{name}.parquet"
            if not wfile.exists():
                raise InputError(f"{wfile} does not exist (scene {scene}, trajectory {name})")
            windows, meta = read_windows(wfile)
            frames = read_frames_table(scene_dir / "frames" / name)
            if not np.array_equal(frames["t_us"].to_numpy(), windows["t_us"].to_numpy()):
                raise InputError(f"{wfile}: stale, its frames differ from frames/{name}/frames.parquet")
            k = len(self.trajectories)
            self.trajectories.append(_Trajectory(scene, name, scene_dir, frames, windows, int(meta["n_events"])))
            ok = windows[f"{self.kind}_covered"].to_numpy(bool)
            items += [(k, int(i)) for i in np.nonzero(ok)[0]]
        self.items = items
        self._readers: dict = {}
        self._readers_pid: int | None = None

    def __len__(self) -> int:
        return len(self.items)

    def _events(self, k: int, i0: int, i1: int, t0: int, t1: int) -> Events:
        """events[i0:i1] of trajectory ``k`` (the windows table's index range),
        through a handle opened once per process (DataLoader workers each open
        their own), checked against the table's event count and window."""
        from gs2e.events.io import H5EventSlicer

        if self._readers_pid != os.getpid():
            self._readers, self._readers_pid = {}, os.getpid()
        tr = self.trajectories[k]
        path = tr.scene_dir / "events" / tr.name / "events.h5"
        if k not in self._readers:
            reader = H5EventSlicer(path)
            if reader.n_events != tr.n_events:
                reader.close()
                raise InputError(f"{path}: {reader.n_events} events, the windows table says "
                                 f"{tr.n_events} (stale windows table: rerun gs2e windows)")
            self._readers[k] = reader
        ev = self._readers[k].read(i0, i1)
        if len(ev) and not (ev.t[0] >= t0 and ev.t[-1] < t1):
            raise InputError(f"{path}: events[{i0}:{i1}] span [{ev.t[0]}, {ev.t[-1]}] us, outside the "
                             f"window [{t0}, {t1}) (stale windows table: rerun gs2e windows)")
        return Events(check_times_us(ev.t, str(path)), ev.x, ev.y, check_polarity01(ev.p, str(path)))

    def __getstate__(self) -> dict:
        # open HDF5 handles stay in their process (spawned workers open their own)
        return {**self.__dict__, "_readers": {}, "_readers_pid": None}

    def __getitem__(self, idx: int) -> dict[str, Any]:
        k, i = self.items[idx]
        tr = self.trajectories[k]
        w, f = tr.windows.iloc[i], tr.frames.iloc[i]
        t0, t1 = int(w[f"{self.kind}_t0_us"]), int(w[f"{self.kind}_t1_us"])
        i0, i1 = int(w[f"{self.kind}_i0"]), int(w[f"{self.kind}_i1"])
        n = i1 - i0
        H, W = int(f["height"]), int(f["width"])
        ev = self._events(k, i0, i1, t0, t1)
        check_events_in_sensor(ev.x, ev.y, W, H, f"{tr.scene}/{tr.name}")
        if self.representation == "voxel":
            events: Any = torch.from_numpy(voxel_grid(ev, (H, W), self.n_bins, t0, t1))
        elif self.representation == "counts":
            events = torch.from_numpy(event_frame(ev, (H, W), t0, t1))
        else:
            events = to_tonic(ev.t, ev.x, ev.y, ev.p, f"{tr.scene}/{tr.name}")
        item = {"scene": tr.scene, "trajectory": tr.name, "frame": i, "t0_us": t0, "t1_us": t1,
                "n_events": n, "events": events,
                "c2w": torch.from_numpy(np.array(f["c2w"], np.float64)),  # a copy: pandas rows are read-only
                "K": torch.tensor([[f["fx"], 0.0, f["cx"]], [0.0, f["fy"], f["cy"]], [0.0, 0.0, 1.0]],
                                  dtype=torch.float64)}
        frames_dir = tr.scene_dir / "frames" / tr.name
        for kind in self.load:
            item[kind] = self._image(frames_dir, kind, i, str(f["file"]))
        return item

    @staticmethod
    def _image(frames_dir: Path, kind: str, i: int, name: str) -> torch.Tensor:
        if kind == "depth":
            p = frames_dir / "depth" / f"{i:06d}.npz"
            if not p.exists():
                raise InputError(f"{p} does not exist (render.write_depth: false? drop 'depth' from load)")
            with np.load(p) as z:
                return torch.from_numpy(z["depth"].astype(np.float32))[None]
        from gs2e.io.images import read_image

        p = frames_dir / kind / name
        if not p.exists():
            raise InputError(f"{p} does not exist (render.write_blur: false? drop '{kind}' from load)")
        return torch.from_numpy(read_image(p).astype(np.float32) / 255.0).permute(2, 0, 1).contiguous()


def collate_windows(batch: list[dict[str, Any]]) -> dict[str, Any]:
    """DataLoader collate function: tensors and numbers are stacked as usual;
    raw (structured-array) events, which differ in length, stay a list."""
    raw = isinstance(batch[0]["events"], np.ndarray)
    out = default_collate([{k: v for k, v in b.items() if not (raw and k == "events")} for b in batch])
    if raw:
        out["events"] = [b["events"] for b in batch]
    return out
