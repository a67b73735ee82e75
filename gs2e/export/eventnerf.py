"""EventNeRF (r00tman/EventNeRF, ``data_loader_split.py``) layout.

What its loader reads, per split ``train``, ``validation``, ``test``::

    <scene>/<split>/pose/NNNNNN.txt        4x4 camera-to-world, OpenCV axes (x right,
                                           y down, z forward), scene inside the unit sphere
    <scene>/<split>/intrinsics/NNNNNN.txt  4x4 (fx, fy, cx, cy; pixel centres +0.5); an
                                           optional 5th row k1 k2 0 0 is not written (= 0)
    <scene>/<split>/rgb/NNNNNN.png         one image per pose (sorted names pair them)
    <scene>/<split>/events/events.npz      exactly one file: x, y (int16), t (float64),
                                           p (int8, -1 OFF / +1 ON)

The loader places pose i of a split at i / (N - 1) * t.max() and takes the
events of [start, end) with ``np.searchsorted`` (data_loader_split.py
L101-124), so gs2e writes each split's times (float64 seconds from its first
frame) on that axis: every event is clipped into its window's loader bounds
(a shift no larger than a frame's distance from the even grid, under 1 us
for render.fps frames; the manifest's ``max_shift_us``) and the file ends
with one zero-polarity event at the last frame's time, which sets t.max()
and lies in no window. The loader's windows then hold
exactly gs2e's windows (gs2e's last, off-grid frame is left out). It
hard-codes H, W = 260, 346: frames of another size are an error unless
``eventnerf_fit`` crops or pads them onto the 346x260 sensor (padded pixels
have no events, which EventNeRF reads as "no brightness change").

``eventnerf.txt`` holds the config keys the layout needs: ``testskip = 1``
(the default 8 keeps one view of a short validation split and no sampler;
ddp_train_nerf.py L446-447, L673), ``is_cycled = False`` and a ``winsize``
that leaves training windows (non-cycled, the loader trains on views
1 + winsize .. N - 1; data_loader_split.py L86-87): ``eventnerf_winsize``,
or min(50, (N - 1) // 2) views. Validation and test views start at their
third view (winsize 1: L86).

Poses are normalised as NeRF++ does (EventNeRF renders only inside the unit
sphere): centre = mean camera centre, radius = 1.1 x the largest distance to a
camera or to 99.9 % of the surface points the frames see. Train on the result
with ``is_colored = False`` (gs2e events come from luminance, not a Bayer
sensor) and ``polarity_offset = 0``; ``eventnerf.txt`` lists these settings.
"""

from __future__ import annotations

import numpy as np

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events
from gs2e.export.common import (ExportOut, SensorFit, check_increasing_bounds, matrix_text, scene_points,
                                times_in_loader_windows, unit_sphere)
from gs2e.export.conventions import signed_polarity

SENSOR_W, SENSOR_H = 346, 260  # data_loader_split.py L137: H, W = 260, 346
SPLITS = ("train", "validation", "test")
MIN_VIEWS = 3  # the loader skips the first 1 + winsize views (winsize >= 1; L86)
WINSIZE_CAP = 50  # EventNeRF's configs/nerf/*.txt and configs/ablation/full.txt: winsize = 50


def intrinsics_matrix(K: np.ndarray) -> np.ndarray:
    """EventNeRF's 4x4 intrinsics file content."""
    out = np.eye(4)
    out[:3, :3] = K
    return out


def evenly_spaced_prefix(frames: np.ndarray, t_us: np.ndarray) -> np.ndarray:
    """The frames from the first on while their spacing stays the median one
    (to 1 us of rounding): render ends a trajectory with a frame at its end
    time, off the fps grid."""
    if len(frames) < 3:
        return frames
    d = np.diff(t_us[frames])
    off = np.flatnonzero(np.abs(d - np.median(d)) > 1)
    return frames if len(off) == 0 else frames[:off[0] + 1]


def split_frames(frames: np.ndarray, holdout_every: int) -> dict[str, np.ndarray]:
    """train = every exported frame; validation = test = every
    ``holdout_every``-th frame (all frames when that leaves fewer than 3)."""
    held = frames[::holdout_every]
    if len(held) < MIN_VIEWS:
        held = frames
    return {"train": frames, "validation": held, "test": held}


def loader_bounds_s(n_views: int, t_max_s: float) -> np.ndarray:
    """The loader's window boundaries of a split with ``n_views`` poses:
    (i / (N - 1)) * t.max() in float64, as data_loader_split.py L102-124
    computes them (a Python float times a numpy float64)."""
    return np.array([i / (n_views - 1) for i in range(n_views)]) * np.float64(t_max_s)


def choose_winsize(n_train_views: int, winsize: int | None) -> int:
    """``winsize`` for a non-cycled train split of ``n_train_views`` poses: the
    loader trains on views 1 + winsize .. N - 1, so winsize <= N - 2; ``None``
    picks min(50, (N - 1) // 2), leaving half the views as window ends."""
    if winsize is None:
        return max(1, min(WINSIZE_CAP, (n_train_views - 1) // 2))
    if winsize > n_train_views - 2:
        raise ConfigError(f"export.eventnerf_winsize = {winsize} leaves no EventNeRF training window: the "
                          f"train split has {n_train_views} views and the loader (is_cycled = False) trains "
                          f"on views 1 + winsize .. {n_train_views - 1}; use at most {n_train_views - 2} "
                          "(or null to choose)")
    return int(winsize)


def loader_events(ev: Events, t_split_us: np.ndarray, where: str) -> dict[str, np.ndarray]:
    """events.npz arrays of one split: times on the loader's axis (see module
    docstring) and a closing zero-polarity event at the last frame's time."""
    t_max_s = (int(t_split_us[-1]) - int(t_split_us[0])) * 1e-6
    bounds = check_increasing_bounds(loader_bounds_s(len(t_split_us), t_max_s), where)
    t = times_in_loader_windows(ev.t, t_split_us, bounds)
    return {"x": np.append(ev.x.astype(np.int16), np.int16(0)),
            "y": np.append(ev.y.astype(np.int16), np.int16(0)),
            "t": np.append(t, bounds[-1]),
            "p": np.append(signed_polarity(ev.p, where), np.int8(0))}


def export_eventnerf(src, out: ExportOut, cfg: dict) -> None:
    t_frames = src.frames["t_us"].to_numpy()
    frames = src.covered_frames()
    on_grid = evenly_spaced_prefix(frames, t_frames)
    if len(on_grid) < len(frames):
        out.warn(f"{len(frames) - len(on_grid)} last frame(s) off the render.fps grid (the "
                 f"trajectory's end) are not exported: the loader assumes evenly spaced poses")
        frames = on_grid
    if len(frames) < MIN_VIEWS:
        raise InputError(f"{src.events_file}: events cover {len(frames)} evenly spaced frames; EventNeRF's "
                         f"loader needs at least {MIN_VIEWS} (it trains on views 1 + winsize ..)")
    fit = SensorFit.centred(src.width, src.height, SENSOR_W, SENSOR_H, cfg["eventnerf_fit"],
                            "EventNeRF (data_loader_split.py)")
    c2w_all = src.c2w(frames)
    norm = unit_sphere(c2w_all[:, :3, 3], scene_points(src, frames))
    splits = split_frames(frames, int(cfg["eventnerf_holdout_every"]))
    winsize = choose_winsize(len(splits["train"]), cfg["eventnerf_winsize"])
    info = {}
    for split, idx in splits.items():
        t0, t1 = int(t_frames[idx[0]]), int(t_frames[idx[-1]])
        ev, dropped = fit.events(src.events(t0, t1))
        for k, i in enumerate(idx):
            name = f"{k:06d}"
            out.text(f"{split}/pose/{name}.txt", matrix_text(norm.apply_c2w(src.c2w([i])[0])))
            out.text(f"{split}/intrinsics/{name}.txt", matrix_text(intrinsics_matrix(fit.K(src.K(i)))))
            out.png(f"{split}/rgb/{name}.png", fit.image(src.image("rgb", i)))
        arrays = loader_events(ev, t_frames[idx], f"EventNeRF {split} split of {src.events_file}")
        np.savez(out.path(f"{split}/events/events.npz"), **arrays)
        shift_us = np.abs(arrays["t"][:-1] - (ev.t - t0) * 1e-6) * 1e6
        if len(ev) == 0:
            out.warn(f"{split}: no events in the exported span")
        first = 1 + (winsize if split == "train" else 1)  # data_loader_split.py L86
        info[split] = {"gs2e_frames": idx.tolist(), "t0_us": t0, "t1_us": t1, "n_events": len(ev),
                       "events_dropped_off_sensor": dropped, "loader_t_max_s": (t1 - t0) * 1e-6,
                       "max_shift_us": float(shift_us.max()) if len(ev) else 0.0,
                       "loader_views": idx[first:].tolist()}
    place = (f"datadir = {out.final.parent}\nscene = {out.final.name}\n" if out.final
             else "# datadir = this folder's parent, scene = its name\n")
    out.text("eventnerf.txt",
             "# EventNeRF config keys for this export (add your experiment's keys)\n" + place +
             "is_colored = False\npolarity_offset = 0.0\nis_cycled = False\n"
             f"trainskip = 1\ntestskip = 1\nwinsize = {winsize}\n")
    out.manifest.update({
        "target": "r00tman/EventNeRF data_loader_split.py",
        "time": "events.npz t: float64 seconds from the split's first frame (t0_us, absolute), each "
                "clipped into its loader window [j/(N-1), (j+1)/(N-1)) x t.max() (< 1 us shift)",
        "polarity": "events.npz p: int8, +1 ON, -1 OFF; the last event (p = 0, x = y = 0) sits at the "
                    "last frame's time: it sets t.max() and is in no loader window",
        "winsize": winsize,
        "poses": "pose/*.txt: camera-to-world, OpenCV axes, after the normalisation",
        "normalisation": norm.to_dict(), "sensor_fit": fit.to_dict(), "splits": info,
    })
