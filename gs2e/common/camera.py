"""Fitting one pinhole camera to another's image: uniform scale about the
image centre, so that a target pixel array is filled (``cover``: an aspect
mismatch crops) or holds the whole view (``contain``: it leaves borders).

Pixel coordinates are continuous with the image corner at (0, 0), the
convention of gs2e's intrinsics: a point x of the (width, height) image maps
to ``s * x + (W_target - s * width) / 2``. Used by the event stage (a
sensor's array) and the render stage (frames from the same camera).
"""

from __future__ import annotations

import numpy as np

from gs2e.common.errors import ConfigError

FITS = ("cover", "contain")
# The largest pixel array gs2e renders or simulates: each side at most 16384 px
# and 64 M pixels (HD event cameras are 1280x720; 16k frames need ~3 GB per
# float32 RGB image). Larger is refused up front, before any allocation.
MAX_SIDE_PX = 16384
MAX_PIXELS = 1 << 26


def size_problem(width: int, height: int) -> str | None:
    """Why a ``width`` x ``height`` pixel array is refused, or None."""
    if width < 1 or height < 1:
        return f"{width}x{height} is empty"
    if width > MAX_SIDE_PX or height > MAX_SIDE_PX or width * height > MAX_PIXELS:
        return (f"{width}x{height} is beyond gs2e's limit ({MAX_SIDE_PX} px a side, "
                f"{MAX_PIXELS // (1 << 20)} M pixels)")
    return None


def fit_scale(width: float, height: float, target_w: int, target_h: int, fit: str = "cover") -> float:
    """Uniform scale from a (width, height) camera image to a target array."""
    if fit not in FITS:
        raise ConfigError(f"sensor fit must be one of {FITS}, got {fit!r}")
    sx, sy = target_w / width, target_h / height
    return max(sx, sy) if fit == "cover" else min(sx, sy)


def render_camera(K: np.ndarray, width: int, height: int, scale: float = 1.0,
                  sensor: tuple[tuple[int, int], str] | None = None) -> tuple[np.ndarray, int, int]:
    """The camera a trajectory is rendered through: (K (3, 3), W, H).

    With ``sensor`` = ((W, H), fit), the sensor's array fitted to the (width,
    height) camera K (:func:`fit_camera`; ``scale`` does not apply); else K
    scaled to ``scale`` x its size (rounded to whole pixels, at least 1);
    ConfigError naming ``render.scale`` when that size is beyond
    :func:`size_problem`'s limit."""
    K = np.asarray(K, np.float64)
    if sensor is not None:
        (W, H), fit = sensor
        return fit_camera(K, width, height, W, H, fit), int(W), int(H)
    W = max(1, int(round(width * scale)))
    H = max(1, int(round(height * scale)))
    why = size_problem(W, H)
    if why:  # before any frame buffer is allocated
        raise ConfigError(f"render.scale={scale:g} on the {width}x{height} camera: the frames' size {why}")
    sx, sy = W / width, H / height
    return np.array([[K[0, 0] * sx, 0, K[0, 2] * sx], [0, K[1, 1] * sy, K[1, 2] * sy],
                     [0, 0, 1.0]]), W, H


def fit_camera(K: np.ndarray, width: int, height: int, target_w: int, target_h: int,
               fit: str = "cover") -> np.ndarray:
    """Intrinsics (3, 3) of a camera with a (target_w, target_h) array fitted
    to the camera K of a (width, height) image: same centre of view, uniform
    scale (square pixels stay square)."""
    s = fit_scale(width, height, target_w, target_h, fit)
    K = np.asarray(K, np.float64)
    return np.array([[K[0, 0] * s, 0.0, K[0, 2] * s + (target_w - s * width) / 2],
                     [0.0, K[1, 1] * s, K[1, 2] * s + (target_h - s * height) / 2],
                     [0.0, 0.0, 1.0]])
