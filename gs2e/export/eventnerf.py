"""EventNeRF (r00tman/EventNeRF, ``data_loader_split.py``) layout.

What its loader reads, per split ``train``, ``validation``, ``test``::

    <scene>/<split>/pose/NNNNNN.txt        4x4 camera-to-world, OpenCV axes (x right,
                                           y down, z forward), scene inside the unit sphere
    <scene>/<split>/intrinsics/NNNNNN.txt  4x4 (fx, fy, cx, cy; pixel centres +0.5); an
                                           optional 5th row k1 k2 0 0 is not written (= 0)
    <scene>/<split>/rgb/NNNNNN.png         one image per pose (sorted names pair them)
    <scene>/<split>/events/events.npz      exactly one file: x, y (int16), t (float64),
                                           p (int8, -1 OFF / +1 ON)

The loader assumes the poses are evenly spaced in time over [0, t.max()] of
the events (pose i at i / (N - 1) * t.max()) and hard-codes H, W = 260, 346.
gs2e frames are evenly spaced (render.fps) but for the trajectory's last
frame, which sits at its end time and is left out; t is written in seconds from the
first exported frame, so pose i sits at t_i exactly and the loader's only
approximation is that t.max() is the last event, not the last frame: the
manifest records that gap (``alignment_gap_us``) and a warning is raised when
it exceeds 1 % of a frame interval. Frames of another size are an error
unless ``eventnerf_fit`` crops or pads them onto the 346x260 sensor (padded
pixels have no events, which EventNeRF reads as "no brightness change").

Poses are normalised as NeRF++ does (EventNeRF renders only inside the unit
sphere): centre = mean camera centre, radius = 1.1 x the largest distance to a
camera or to 99.9 % of the surface points the frames see. Train on the result
with ``is_colored = False`` (gs2e events come from luminance, not a Bayer
sensor) and ``polarity_offset = 0``; ``eventnerf.txt`` lists these settings.
"""

from __future__ import annotations

import numpy as np

from gs2e.export.common import ExportOut, SensorFit, matrix_text, scene_points, unit_sphere
from gs2e.export.conventions import signed_polarity

SENSOR_W, SENSOR_H = 346, 260  # data_loader_split.py: H, W = 260, 346
SPLITS = ("train", "validation", "test")
MIN_VIEWS = 3  # the loader skips the first 1 + winsize views (winsize >= 1)


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


def export_eventnerf(src, out: ExportOut, cfg: dict) -> None:
    t_frames = src.frames["t_us"].to_numpy()
    frames = src.covered_frames()
    on_grid = evenly_spaced_prefix(frames, t_frames)
    if len(on_grid) < len(frames):
        out.warn(f"{len(frames) - len(on_grid)} last frame(s) off the render.fps grid (the "
                 f"trajectory's end) are not exported: the loader assumes evenly spaced poses")
        frames = on_grid
    fit = SensorFit.centred(src.width, src.height, SENSOR_W, SENSOR_H, cfg["eventnerf_fit"],
                            "EventNeRF (data_loader_split.py)")
    c2w_all = src.c2w(frames)
    norm = unit_sphere(c2w_all[:, :3, 3], scene_points(src, frames))
    dt_frame = float(np.median(np.diff(t_frames[frames])))
    splits = split_frames(frames, int(cfg["eventnerf_holdout_every"]))
    info = {}
    for split, idx in splits.items():
        t0, t1 = int(t_frames[idx[0]]), int(t_frames[idx[-1]])
        ev = src.events(t0, t1)
        ev, dropped = fit.events(ev)
        for k, i in enumerate(idx):
            name = f"{k:06d}"
            out.text(f"{split}/pose/{name}.txt", matrix_text(norm.apply_c2w(src.c2w([i])[0])))
            out.text(f"{split}/intrinsics/{name}.txt", matrix_text(intrinsics_matrix(fit.K(src.K(i)))))
            out.png(f"{split}/rgb/{name}.png", fit.image(src.image("rgb", i)))
        np.savez(out.path(f"{split}/events/events.npz"),
                 x=ev.x.astype(np.int16), y=ev.y.astype(np.int16),
                 t=(ev.t - t0).astype(np.float64) * 1e-6,
                 p=signed_polarity(ev.p, str(src.events_file)))
        gap = (t1 - int(ev.t[-1])) if len(ev) else None
        if len(ev) == 0:
            out.warn(f"{split}: no events in the exported span; EventNeRF cannot place windows")
        elif gap > 0.01 * dt_frame * (len(idx) > 1):
            out.warn(f"{split}: the last event is {gap} us before the last frame; the loader's "
                     f"window boundaries (i/(N-1) x t.max) shift by up to that")
        info[split] = {"gs2e_frames": idx.tolist(), "t0_us": t0, "t1_us": t1, "n_events": len(ev),
                       "events_dropped_off_sensor": dropped, "alignment_gap_us": gap}
    out.text("eventnerf.txt",
             "# settings for EventNeRF's config (datadir = this folder's parent, scene = its name)\n"
             "is_colored = False\npolarity_offset = 0.0\nis_cycled = False\n")
    out.manifest.update({
        "target": "r00tman/EventNeRF data_loader_split.py",
        "time": "events.npz t: float64 seconds from the split's first frame (t0_us, absolute)",
        "polarity": "events.npz p: int8, +1 ON, -1 OFF",
        "poses": "pose/*.txt: camera-to-world, OpenCV axes, after the normalisation",
        "normalisation": norm.to_dict(), "sensor_fit": fit.to_dict(), "splits": info,
    })
