"""Frame sources: anything that yields ``(t_us, frame)`` for the event models.

Protocol (see :mod:`gs2e.events.models`): ``t_us`` int microseconds, strictly
increasing; ``frame`` float32 (H, W) LINEAR luminance in [0, 1]. A source
object also has ``shape`` (H, W), ``n_frames`` (int or None) and ``name``.

Adapters:
- a folder of images (png/jpg/tif/exr...) in natural name order (frame2
  before frame10; hidden files skipped) + a timestamps file
  (one time per line; microseconds as integers, or seconds with decimals when
  ``time_unit="s"``) or a frame rate;
- a video file (timestamps from its frame rate or ``fps``);
- an array file: ``.npy`` (N, H, W) with ``fps``, or ``.npz`` with ``frames``
  (N, H, W) and ``t_us`` (N,) (``timestamps`` is accepted too);
- any iterable of ``(t_us, frame)`` in memory (:class:`IterSource`).

8/16-bit images and videos are sRGB-encoded: ``encoding="srgb"`` (default)
undoes the transfer curve; ``"linear"`` takes values as they are. Colour is
reduced to luminance with Rec. 709 weights on linear RGB.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Callable, Iterable, Iterator, TypeVar

import numpy as np

from gs2e.common.errors import InputError
from gs2e.common.color import REC709 as _REC709, srgb_to_linear
from gs2e.common.settings import require
from gs2e.io.images import list_images
from gs2e.common.camera import fit_scale
from gs2e.events.sensors import fit_frame, get_sensor
from gs2e.events.settings import EventSettings

_T = TypeVar("_T")
_R = TypeVar("_R")


def read_ahead(fn: Callable[[_T], _R], items: Iterable[_T], depth: int = 8) -> Iterator[_R]:
    """``fn(item)`` for each item, in order, computed up to ``depth`` items
    ahead in one background thread. For image decoding: OpenCV releases the
    GIL while it decodes (and the event kernels release it while they run),
    so reading overlaps the models. An exception from ``fn`` is raised when
    its item's turn comes, as without read-ahead."""
    from concurrent.futures import ThreadPoolExecutor

    it = iter(items)
    ex = ThreadPoolExecutor(1, thread_name_prefix="gs2e-read-ahead")
    try:
        pending = deque(ex.submit(fn, x) for _, x in zip(range(depth), it))
        while pending:
            result = pending.popleft().result()
            for x in it:
                pending.append(ex.submit(fn, x))
                break
            yield result
    finally:  # also when the consumer stops early: drop what was not started
        ex.shutdown(wait=True, cancel_futures=True)


IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".exr", ".pgm", ".ppm")
VIDEO_EXTS = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")


def to_linear_luminance(img: np.ndarray, encoding: str = "srgb", where: str = "frame") -> np.ndarray:
    """uint8 / uint16 / float image (H, W) or (H, W, 3|4, RGB order) -> float32
    linear luminance in [0, 1]. Floats are taken as already in [0, 1]."""
    a = np.asarray(img)
    if a.dtype == np.uint8:
        x = a.astype(np.float64) / 255.0
    elif a.dtype == np.uint16:
        x = a.astype(np.float64) / 65535.0
    elif np.issubdtype(a.dtype, np.floating):
        x = a.astype(np.float64)
    else:
        raise InputError(f"{where}: unsupported pixel type {a.dtype}")
    if encoding == "srgb":
        x = srgb_to_linear(np.clip(x, 0.0, 1.0)) if not np.issubdtype(a.dtype, np.floating) else x
    elif encoding != "linear":
        raise InputError(f"{where}: unknown encoding '{encoding}' (srgb or linear)")
    if x.ndim == 3:
        if x.shape[2] == 1:
            x = x[..., 0]
        elif x.shape[2] in (3, 4):
            x = x[..., :3] @ _REC709
        else:
            raise InputError(f"{where}: image with {x.shape[2]} channels")
    elif x.ndim != 2:
        raise InputError(f"{where}: expected an (H, W) or (H, W, C) image, got shape {a.shape}")
    return x.astype(np.float32)


def read_timestamps(path: str | Path, time_unit: str = "us") -> np.ndarray:
    """One timestamp per line (first column; '#' comments) -> int64 microseconds."""
    path = Path(path)
    try:
        vals = np.loadtxt(path, dtype=np.float64, comments="#", ndmin=2)[:, 0]
    except (OSError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: cannot read timestamps ({exc})") from exc
    if not np.all(np.isfinite(vals)):
        raise InputError(f"{path}: timestamps contain NaN or inf")
    scale = {"us": 1.0, "ms": 1e3, "s": 1e6}.get(time_unit)
    if scale is None:
        raise InputError(f"{path}: unknown time unit '{time_unit}' (us, ms, s)")
    t = np.round(vals * scale).astype(np.int64)
    check_timestamps(t, str(path))
    return t


def check_timestamps(t: np.ndarray, where: str) -> None:
    d = np.diff(t)
    if np.any(d <= 0):
        i = int(np.argmax(d <= 0))
        raise InputError(f"{where}: timestamps must increase strictly (after rounding to us); "
                         f"entry {i + 2} is {t[i + 1]} us after {t[i]} us")


def _fps_times(n: int, fps: float | None, where: str) -> np.ndarray:
    if not fps or fps <= 0:
        raise InputError(f"{where}: needs a timestamps file or a frame rate (--fps)")
    t = np.round(np.arange(n) * (1e6 / fps)).astype(np.int64)
    check_timestamps(t, where)
    return t


class IterSource:
    """Wrap an in-memory iterable of (t_us, frame) (frames as in the protocol)."""

    def __init__(self, items: Iterable[tuple[int, np.ndarray]], shape=None, n_frames=None,
                 name: str = "frames"):
        self._items = items
        self.shape = shape
        self.n_frames = n_frames
        self.name = name

    def __iter__(self):
        return iter(self._items)


class ImageFolderSource:
    def __init__(self, folder: Path, timestamps: str | Path | None, fps: float | None,
                 encoding: str = "srgb", time_unit: str = "us"):
        self.folder = Path(folder)
        self.files = list_images(self.folder, IMAGE_EXTS)
        if not self.files:
            raise InputError(f"{folder}: no images ({', '.join(IMAGE_EXTS)})")
        if timestamps is not None:
            self.t_us = read_timestamps(timestamps, time_unit)
            if len(self.t_us) != len(self.files):
                raise InputError(f"{timestamps}: {len(self.t_us)} timestamps for "
                                 f"{len(self.files)} images in {folder}")
        else:
            self.t_us = _fps_times(len(self.files), fps, str(folder))
        self.encoding = encoding
        self.name = str(folder)
        self.n_frames = len(self.files)
        self.shape = self._read(self.files[0]).shape

    def _read(self, p: Path) -> np.ndarray:
        import cv2
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(f"{p}: cannot read image")
        if img.ndim == 3:
            img = img[..., [2, 1, 0] + ([3] if img.shape[2] == 4 else [])]  # BGR(A) -> RGB(A)
        return to_linear_luminance(img, self.encoding, str(p))

    def __iter__(self) -> Iterator[tuple[int, np.ndarray]]:
        # about two batches of frames ahead (the models take 32 at a time), at most ~64 MB
        depth = int(np.clip(64e6 // (4 * self.shape[0] * self.shape[1]), 2, 64))
        for t, p, f in zip(self.t_us, self.files, read_ahead(self._read, self.files, depth)):
            if f.shape != self.shape:
                raise InputError(f"{p}: shape {f.shape} differs from the first image's {self.shape}")
            yield int(t), f


class VideoSource:
    def __init__(self, path: Path, fps: float | None = None, timestamps=None,
                 encoding: str = "srgb", time_unit: str = "us"):
        import cv2
        self.path = Path(path)
        cap = cv2.VideoCapture(str(self.path))
        if not cap.isOpened():
            raise InputError(f"{path}: cannot open video")
        self.fps = float(fps or cap.get(cv2.CAP_PROP_FPS) or 0)
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        W, H = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        cap.release()
        self.shape = (H, W)
        self.n_frames = n if n > 0 else None
        self.ts_file = read_timestamps(timestamps, time_unit) if timestamps else None
        if self.ts_file is None and not self.fps > 0:
            raise InputError(f"{path}: video has no frame rate; pass --fps or a timestamps file")
        self.encoding = encoding
        self.name = str(path)

    def __iter__(self):
        import cv2
        cap = cv2.VideoCapture(str(self.path))
        i = 0
        try:
            while True:
                ok, img = cap.read()
                if not ok:
                    break
                if self.ts_file is not None:
                    if i >= len(self.ts_file):
                        raise InputError(f"{self.path}: more frames than timestamps")
                    t = int(self.ts_file[i])
                else:
                    t = int(round(i * 1e6 / self.fps))
                yield t, to_linear_luminance(img[..., ::-1], self.encoding, f"{self.path} frame {i}")
                i += 1
        finally:
            cap.release()
        if i == 0:
            raise InputError(f"{self.path}: no frames decoded")


class ArraySource:
    def __init__(self, path: Path, fps: float | None = None, timestamps=None,
                 encoding: str = "linear", time_unit: str = "us"):
        self.path = Path(path)
        try:
            if self.path.suffix.lower() == ".npz":
                z = np.load(self.path)
                if "frames" not in z:
                    raise InputError(f"{path}: npz needs an array 'frames' (N, H, W)")
                frames = z["frames"]
                tkey = next((k for k in ("t_us", "timestamps") if k in z), None)
                t = z[tkey] if tkey else None
            else:
                frames, t = np.load(self.path, mmap_mode="r"), None
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: cannot read array file ({exc})") from exc
        if frames.ndim not in (3, 4):
            raise InputError(f"{path}: frames must be (N, H, W) or (N, H, W, C), got {frames.shape}")
        if timestamps is not None:
            t = read_timestamps(timestamps, time_unit)
        if t is None:
            t = _fps_times(len(frames), fps, str(path))
        t = np.asarray(t)
        if t.shape != (len(frames),):
            raise InputError(f"{path}: {t.shape} timestamps for {len(frames)} frames")
        if np.issubdtype(t.dtype, np.floating):
            if not np.all(np.isfinite(t)) or np.any(t != np.round(t)):
                raise InputError(f"{path}: timestamps must be integer microseconds")
        t = t.astype(np.int64)
        check_timestamps(t, str(path))
        self.frames, self.t_us, self.encoding = frames, t, encoding
        self.shape = tuple(frames.shape[1:3])
        self.n_frames = len(frames)
        self.name = str(path)

    def __iter__(self):
        for i in range(self.n_frames):
            yield int(self.t_us[i]), to_linear_luminance(np.asarray(self.frames[i]), self.encoding,
                                                         f"{self.path} frame {i}")


def open_frame_source(path: str | Path, timestamps: str | Path | None = None,
                      fps: float | None = None, encoding: str | None = None,
                      time_unit: str = "us"):
    """Frame source for a folder of images, a video or an array file.
    ``encoding`` defaults to "srgb" for images/videos and "linear" for arrays."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if p.is_dir():
        return ImageFolderSource(p, timestamps, fps, encoding or "srgb", time_unit)
    suf = p.suffix.lower()
    if suf in (".npy", ".npz"):
        return ArraySource(p, fps, timestamps, encoding or "linear", time_unit)
    if suf in VIDEO_EXTS:
        return VideoSource(p, fps, timestamps, encoding or "srgb", time_unit)
    raise InputError(f"{p}: unsupported frame input (folder of images, video "
                     f"{'/'.join(VIDEO_EXTS)}, or .npy/.npz)")


class SensorFrames:
    """A frame source as an ``events.sensor`` sees it: every frame scaled
    about its centre to the sensor's pixel array (:func:`gs2e.events.sensors.fit_frame`)."""

    def __init__(self, frames, settings: "EventSettings"):
        settings = require(settings, EventSettings, "SensorFrames")
        self.src, self.fit = frames, settings.sensor_fit
        self.sensor = get_sensor(settings)
        self.width, self.height = self.sensor.size
        self.name = getattr(frames, "name", "frames")
        self.n_frames = getattr(frames, "n_frames", None)
        self.shape = (self.height, self.width)
        self.camera = {"width": self.width, "height": self.height, "sensor": self.sensor.name,
                       "sensor_fit": self.fit, "input_shape": None, "scale": None}

    def __iter__(self):
        for t, f in self.src:
            f = np.asarray(f)
            if self.camera["input_shape"] is None and f.ndim == 2:
                self.camera["input_shape"] = list(f.shape)
                self.camera["scale"] = fit_scale(f.shape[1], f.shape[0], self.width,
                                                 self.height, self.fit)
            yield t, (fit_frame(f, self.width, self.height, self.fit) if f.ndim == 2 else f)
