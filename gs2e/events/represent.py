"""Dense representations of events: event frames, voxel grids, preview video."""

from __future__ import annotations

import os
from typing import Iterable

import numpy as np

from gs2e.events.models import Events


def window_events(ev: Events, t0_us: int | None, t1_us: int | None) -> Events:
    """The events with t0_us <= t < t1_us of a time-sorted stream (None: open end)."""
    if t0_us is None and t1_us is None:
        return ev
    i0 = 0 if t0_us is None else int(np.searchsorted(ev.t, t0_us, side="left"))
    i1 = len(ev) if t1_us is None else int(np.searchsorted(ev.t, t1_us, side="left"))
    return Events(ev.t[i0:i1], ev.x[i0:i1], ev.y[i0:i1], ev.p[i0:i1])


def event_frame(ev: Events, shape: tuple[int, int], t0_us: int | None = None,
                t1_us: int | None = None, mode: str = "counts") -> np.ndarray:
    """Histogram of the events with t0 <= t < t1 (us; sorted input).

    mode "counts": (2, H, W) int32, [0] OFF counts, [1] ON counts;
    mode "signed": (H, W) int32, ON minus OFF.
    """
    e = window_events(ev, t0_us, t1_us)
    H, W = shape
    idx = e.y.astype(np.int64) * W + e.x.astype(np.int64)
    if mode == "counts":
        # bincount, not np.add.at: same sums, 10-50x faster
        return np.bincount(idx + e.p.astype(np.int64) * H * W,
                           minlength=2 * H * W).astype(np.int32).reshape(2, H, W)
    if mode == "signed":
        return np.bincount(idx, weights=2.0 * e.p - 1.0, minlength=H * W).astype(np.int32).reshape(H, W)
    raise ValueError(f"unknown mode {mode!r}")


def voxel_grid(ev: Events, shape: tuple[int, int], n_bins: int, t0_us: int | None = None,
               t1_us: int | None = None) -> np.ndarray:
    """(n_bins, H, W) float32 voxel grid (Zhu et al. 2019): each event adds its
    polarity (+1 ON, -1 OFF) to the two nearest time bins with linear weights,
    time normalised so t0 -> bin 0 and t1 -> bin n_bins - 1."""
    e = window_events(ev, t0_us, t1_us)
    H, W = shape
    if len(e) == 0:
        return np.zeros((n_bins, H, W), np.float32)
    a = float(e.t[0] if t0_us is None else t0_us)
    b = float(e.t[-1] if t1_us is None else t1_us)
    tn = (e.t.astype(np.float64) - a) / max(b - a, 1.0) * (n_bins - 1)
    tn = np.clip(tn, 0, n_bins - 1)
    lo = np.floor(tn).astype(np.int64)
    w_hi = tn - lo
    pol = 2.0 * e.p - 1.0
    pix = e.y.astype(np.int64) * W + e.x.astype(np.int64)
    hi = np.minimum(lo + 1, n_bins - 1)
    # one bincount over (lower-bin, upper-bin) contributions: float64 sums in
    # event order, as sequential adds would give, at bincount's speed
    grid = np.bincount(np.concatenate([lo * H * W + pix, hi * H * W + pix]),
                       weights=np.concatenate([pol * (1.0 - w_hi), pol * w_hi * (hi != lo)]),
                       minlength=n_bins * H * W)
    return grid.reshape(n_bins, H, W).astype(np.float32)


def render_overlay(frame_lin: np.ndarray, ev_frame: np.ndarray) -> np.ndarray:
    """RGB uint8 image: the frame (sRGB-encoded grey) with ON events in red-ish
    blue and OFF in red; ``ev_frame`` is (2, H, W) counts."""
    g = np.clip(frame_lin, 0, 1)
    g = np.where(g <= 0.0031308, 12.92 * g, 1.055 * np.power(g, 1 / 2.4) - 0.055)
    img = np.repeat((g * 200).astype(np.uint8)[..., None], 3, axis=2)
    off, on = ev_frame[0] > 0, ev_frame[1] > 0
    img[on] = (40, 120, 255)
    img[off] = (255, 40, 40)
    img[on & off] = (255, 255, 255)
    return img


class PreviewWriter:
    """mp4 preview of events over the frames (cv2.VideoWriter, codec mp4v),
    written atomically. Call ``add(frame_lin, events, t0, t1)`` per frame; only
    every ``every``-th frame becomes a video frame (accumulating events)."""

    def __init__(self, path: str | os.PathLike, shape: tuple[int, int], fps: float = 30.0,
                 every: int = 1, max_frames: int = 3000):
        import tempfile
        from pathlib import Path

        import cv2

        from gs2e.common.atomic import default_file_mode, owner_tag

        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # named like gs2e.common.atomic's temporaries, so a killed job's is swept
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.tmp-{owner_tag()}-", suffix=".mp4",
                                   dir=self.path.parent)
        os.close(fd)
        os.chmod(tmp, default_file_mode())
        self.tmp = tmp
        H, W = shape
        self.shape = shape
        self.vw = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"mp4v"), fps, (W, H))
        if not self.vw.isOpened():
            raise OSError(f"{path}: cannot open a video writer (mp4v)")
        self.every, self.max_frames = max(1, int(every)), int(max_frames)
        self.k = 0
        self.written = 0
        self.acc = np.zeros((2, H, W), np.int32)

    def add(self, frame_lin: np.ndarray, ev: Events) -> None:
        if self.written >= self.max_frames:
            return
        self.acc += event_frame(ev, self.shape)
        self.k += 1
        if self.k % self.every == 0:
            img = render_overlay(frame_lin, self.acc)
            self.vw.write(img[..., ::-1].copy())
            self.acc[:] = 0
            self.written += 1

    def __enter__(self) -> "PreviewWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(ok=exc_type is None)

    def close(self, ok: bool = True) -> None:
        self.vw.release()
        if ok and self.written > 0:
            os.replace(self.tmp, self.path)
        else:
            try:
                os.unlink(self.tmp)
            except FileNotFoundError:
                pass


def write_preview(path, frames: Iterable[tuple[int, np.ndarray]], ev: Events, fps: float = 30.0,
                  every: int = 1) -> int:
    """Preview video of in-memory events over a frame source; returns the number
    of video frames written."""
    pw = None
    prev_t = None
    try:
        for t, f in frames:
            if pw is None:
                pw = PreviewWriter(path, f.shape, fps, every)
            if prev_t is not None:
                pw.add(f, window_events(ev, prev_t, t))
            prev_t = t
        n = pw.written if pw else 0
    except BaseException:
        if pw:
            pw.close(ok=False)
        raise
    if pw:
        pw.close(ok=True)
    return n
