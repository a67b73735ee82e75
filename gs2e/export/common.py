"""Shared parts of the exporters: the output being written, world
normalisations the targets need, intrinsics checks, sensor fitting."""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.events.models import Events
from gs2e.io.images import write_png

log = get_logger("gs2e.export")

MANIFEST = "gs2e_export.json"


@dataclass
class ExportOut:
    """An export folder being written (inside an atomic_dir) and its manifest."""

    root: Path
    fmt: str
    manifest: dict[str, Any] = field(default_factory=dict)
    final: Path | None = None  # where the folder lands (for configs that need a path)

    def __post_init__(self) -> None:
        self.manifest.setdefault("format", self.fmt)
        self.manifest.setdefault("warnings", [])

    def path(self, rel: str) -> Path:
        p = self.root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        return p

    def text(self, rel: str, content: str) -> None:
        self.path(rel).write_text(content)

    def png(self, rel: str, rgb: np.ndarray, params: list[int] | None = None) -> None:
        write_png(self.path(rel), rgb, params)

    def same_as(self, rel: str, written: str) -> None:
        """``rel`` with the content of the already written ``written``: a hard
        link (no extra space), a copy where the file system has none."""
        dst, src = self.path(rel), self.root / written
        try:
            os.link(src, dst)
        except OSError:
            shutil.copyfile(src, dst)

    def warn(self, msg: str) -> None:
        """Something the target reads differently from gs2e: logged and kept."""
        log.warning("%s export: %s", self.fmt, msg)
        self.manifest["warnings"].append(msg)

    def write_manifest(self) -> None:
        self.path(MANIFEST).write_text(json.dumps(self.manifest, indent=2, sort_keys=True,
                                                  default=_jsonable) + "\n")


def _jsonable(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def matrix_text(m: np.ndarray) -> str:
    """Rows of a matrix as whitespace-separated text (full float64 precision)."""
    return "\n".join(" ".join(repr(float(v)) for v in row) for row in np.atleast_2d(m)) + "\n"


# ------------------------------------------------------------------ geometry
@dataclass(frozen=True)
class Similarity:
    """World normalisation x' = scale * (x + translate); poses keep their rotation."""

    translate: np.ndarray
    scale: float

    def apply_c2w(self, c2w: np.ndarray) -> np.ndarray:
        out = np.array(c2w, np.float64, copy=True)
        out[..., :3, 3] = (out[..., :3, 3] + self.translate) * self.scale
        return out

    def apply_points(self, xyz: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz, np.float64) + self.translate) * self.scale

    def to_dict(self) -> dict:
        return {"translate": [float(v) for v in self.translate], "scale": float(self.scale),
                "rule": "x_export = scale * (x_gs2e + translate); rotations unchanged"}


def backprojected_points(K: np.ndarray, c2w: np.ndarray, depth: np.ndarray, mask: np.ndarray,
                         max_points: int = 4000) -> np.ndarray:
    """World points (P, 3) of the masked pixels of a depth map (z along the
    optical axis, pixel centres at +0.5), evenly subsampled to ``max_points``."""
    v, u = np.nonzero(mask)
    if len(u) > max_points:
        pick = np.linspace(0, len(u) - 1, max_points).astype(np.int64)
        u, v = u[pick], v[pick]
    z = depth[v, u].astype(np.float64)
    x = (u + 0.5 - K[0, 2]) / K[0, 0] * z
    y = (v + 0.5 - K[1, 2]) / K[1, 1] * z
    cam = np.stack([x, y, z], 1)
    return cam @ c2w[:3, :3].T + c2w[:3, 3]


def scene_points(src, frames: np.ndarray, n_views: int = 8) -> np.ndarray:
    """Surface points seen by the exported frames (depth of up to ``n_views``
    of them, pixels the model covers), or the SfM points when no depth exists."""
    pick = np.unique(np.linspace(0, len(frames) - 1, min(n_views, len(frames))).astype(int))
    pts = []
    for k in pick:
        i = int(frames[k])
        try:
            d = src.depth(i)
        except InputError:
            pts = []
            break
        m = (src.alpha(i) > 0.5) & np.isfinite(d) & (d > 0)
        pts.append(backprojected_points(src.K(i), src.c2w([i])[0], d, m))
    if pts:
        return np.concatenate(pts)
    return src.points()[0]


def unit_sphere(centres: np.ndarray, points: np.ndarray, margin: float = 1.1) -> Similarity:
    """NeRF++'s normalisation (centre = mean camera centre, radius = margin x
    the largest camera distance), enlarged so that 99.9 % of the scene's
    surface points are inside the unit sphere too (EventNeRF renders only
    inside it)."""
    centre = centres.mean(0)
    r = float(np.max(np.linalg.norm(centres - centre, axis=1))) if len(centres) else 0.0
    if len(points):
        r = max(r, float(np.percentile(np.linalg.norm(points - centre, axis=1), 99.9)))
    if not r > 0:
        raise InputError("cannot normalise the scene: the cameras coincide and no scene point is known")
    return Similarity(-centre, 1.0 / (margin * r))


def check_centred_square_pixels(K: np.ndarray, width: int, height: int, target: str,
                                 tol_px: float = 1e-3) -> None:
    """Targets that derive intrinsics from one focal length assume fx = fy and
    the principal point at the image centre (pixel centres at +0.5)."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if abs(fx - fy) > tol_px or abs(cx - width / 2) > tol_px or abs(cy - height / 2) > tol_px:
        raise InputError(f"{target} reads one focal length and puts the principal point at the image "
                         f"centre; these frames have fx={fx:.4f} fy={fy:.4f} cx={cx:.4f} cy={cy:.4f} "
                         f"for {width}x{height} (needs fx = fy, cx = W/2, cy = H/2)")


# ------------------------------------------------------------------ sensor fit
@dataclass(frozen=True)
class SensorFit:
    """Placing a (width, height) image centred on a fixed target sensor:
    pixel (x, y) -> (x - ox, y - oy); ox, oy > 0 crop, < 0 pad."""

    ox: int
    oy: int
    width: int
    height: int

    @classmethod
    def centred(cls, width: int, height: int, target_w: int, target_h: int, mode: str,
                target: str) -> "SensorFit":
        if (width, height) == (target_w, target_h):
            return cls(0, 0, target_w, target_h)
        grow = width < target_w or height < target_h
        shrink = width > target_w or height > target_h
        if mode == "error" or (mode == "crop" and grow) or (mode == "pad" and shrink):
            need = ("crop" if not grow else "pad" if not shrink else "a frame size that fits one way")
            raise InputError(f"{target} hard-codes a {target_w}x{target_h} sensor; these frames are "
                             f"{width}x{height}: render at that size, or export with the sensor fit "
                             f"'{need}' (export.eventnerf_fit)")
        return cls((width - target_w) // 2, (height - target_h) // 2, target_w, target_h)

    def image(self, img: np.ndarray) -> np.ndarray:
        """Crop/pad (black) an (H, W, ...) image onto the target sensor."""
        out = np.zeros((self.height, self.width) + img.shape[2:], img.dtype)
        h, w = img.shape[:2]
        sx0, sy0 = max(self.ox, 0), max(self.oy, 0)
        dx0, dy0 = max(-self.ox, 0), max(-self.oy, 0)
        cw, ch = min(w - sx0, self.width - dx0), min(h - sy0, self.height - dy0)
        out[dy0:dy0 + ch, dx0:dx0 + cw] = img[sy0:sy0 + ch, sx0:sx0 + cw]
        return out

    def K(self, K: np.ndarray) -> np.ndarray:
        out = np.array(K, np.float64, copy=True)
        out[0, 2] -= self.ox
        out[1, 2] -= self.oy
        return out

    def events(self, ev: Events) -> tuple[Events, int]:
        """Events moved onto the sensor; those that fall off it are dropped
        (returns the kept events and the number dropped)."""
        x = ev.x.astype(np.int64) - self.ox
        y = ev.y.astype(np.int64) - self.oy
        keep = (x >= 0) & (x < self.width) & (y >= 0) & (y < self.height)
        return (Events(ev.t[keep], x[keep].astype(np.uint16), y[keep].astype(np.uint16), ev.p[keep]),
                int(len(ev) - keep.sum()))

    def to_dict(self) -> dict:
        return {"offset_x": self.ox, "offset_y": self.oy, "width": self.width, "height": self.height,
                "rule": "x_export = x - offset_x, y_export = y - offset_y; cx, cy shift the same; "
                        "positive offset crops, negative pads (padded pixels have no events)"}


# ------------------------------------------------------------------ loader time axes
def check_increasing_bounds(bounds: np.ndarray, where: str) -> np.ndarray:
    """A loader's window boundaries must be strictly increasing in its dtype
    (frames closer than its time resolution cannot be told apart)."""
    if bounds.size > 1 and np.any(np.diff(bounds) <= 0):
        raise InputError(f"{where}: frame times collapse in the loader's {bounds.dtype} time axis "
                         "(frames closer than its resolution)")
    return bounds


def times_in_loader_windows(t_us: np.ndarray, t_frames_us: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """Event times (int us) on a loader's time axis (seconds from the first
    frame, in ``bounds.dtype``) such that the loader's test ``bounds[k-1] <= t <
    bounds[k]`` selects exactly the events gs2e's windows table puts in
    ``[t_frames_us[k-1], t_frames_us[k])``.

    Each time is its offset in seconds, rounded to the dtype and clipped into
    its window's loader bounds: a shift no larger than the rounding between
    gs2e's frame times and the loader's boundaries. Every event must lie in
    ``[t_frames_us[0], t_frames_us[-1])``."""
    t_us = np.asarray(t_us, np.int64)
    t_frames_us = np.asarray(t_frames_us, np.int64)
    k = np.searchsorted(t_frames_us, t_us, side="right")  # t_{k-1} <= t < t_k
    if t_us.size and (k.min() < 1 or k.max() > len(t_frames_us) - 1):
        raise ValueError("events outside the exported frames' span")
    dtype = bounds.dtype
    s = ((t_us - t_frames_us[0]) * 1e-6).astype(dtype)
    below_next = np.nextafter(bounds[k], dtype.type(-np.inf))  # largest value < bounds[k]
    return np.minimum(np.maximum(s, bounds[k - 1]), below_next)


def angle_x(K: np.ndarray, width: int) -> float:
    """Horizontal field of view (radians) of a centred pinhole camera."""
    return 2.0 * math.atan(0.5 * width / K[0, 0])
