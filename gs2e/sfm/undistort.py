"""Views undistorted to COLMAP's PINHOLE cameras with OpenCV.

COLMAP's undistorter writes each view with scalar bilinear lookups and a
slow PNG encoder: 0.56 s of CPU per 1920x1440 view on an AVX2 machine, a
fifth of a whole SfM run. COLMAP still decides the undistorted cameras
(``pycolmap.undistort_images`` of one view writes the whole undistorted
model); the views are resampled here with OpenCV's SIMD remap: bilinear
like COLMAP's, with weights in 1/32 px, so values differ from COLMAP's by at
most a few levels (tests/test_sfm.py).
"""

from __future__ import annotations

import numpy as np

# COLMAP camera model -> names of its parameters in OpenCV's distortion
# vector (k1, k2, p1, p2, k3, k4, k5, k6); those absent are zero.
OPENCV_DISTORTION = {
    "SIMPLE_PINHOLE": (),
    "PINHOLE": (),
    "SIMPLE_RADIAL": ("k1",),
    "RADIAL": ("k1", "k2"),
    "OPENCV": ("k1", "k2", "p1", "p2"),
    "FULL_OPENCV": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
}
_DIST_ORDER = ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6")


def opencv_camera(model: str, params) -> tuple[np.ndarray, np.ndarray]:
    """(K, dist) in OpenCV's conventions of a COLMAP camera (``model``,
    ``params`` in COLMAP's order): K (3, 3) with the principal point moved
    by -0.5 px (OpenCV puts the centre of the top-left pixel at 0, COLMAP at
    0.5), dist (8,) in OpenCV's order. KeyError for a model OpenCV's
    distortion cannot express (fisheye, FOV, ...)."""
    names = OPENCV_DISTORTION[model]
    p = [float(v) for v in params]
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy, extra = p[1], p[2], p[3:]
    else:
        fx, fy, cx, cy, extra = p[0], p[1], p[2], p[3], p[4:]
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    coeffs = dict(zip(names, extra))
    return K, np.array([coeffs.get(n, 0.0) for n in _DIST_ORDER])


def undistortion_maps(src_model: str, src_params, dst_params, dst_size: tuple[int, int]):
    """OpenCV remap tables from a distorted COLMAP camera to its undistorted
    PINHOLE camera (``dst_params`` = fx, fy, cx, cy; ``dst_size`` = (W, H)):
    for every pixel of the undistorted view, where to read the photo."""
    import cv2

    K, dist = opencv_camera(src_model, src_params)
    K_new, _ = opencv_camera("PINHOLE", dst_params)
    return cv2.initUndistortRectifyMap(K, dist, None, K_new, tuple(int(v) for v in dst_size), cv2.CV_16SC2)


def undistort_image(rgb: np.ndarray, maps) -> np.ndarray:
    """A photo (H, W, C) resampled through ``maps`` (bilinear; black where
    the undistorted view sees past the photo's edge)."""
    import cv2

    return cv2.remap(rgb, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def bilinear_colors(rgb: np.ndarray, xy_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Colours of a photo at sub-pixel points, as COLMAP samples them for its
    3D points (bilinear, in COLMAP's pixel convention: the centre of the
    top-left pixel at (0.5, 0.5)).

    Parameters
    ----------
    rgb : (H, W, 3) uint8 photo.
    xy_px : (N, 2) points (px).

    Returns
    -------
    colors : (N, 3) float64, 0 where not valid.
    valid : (N,) bool, False where the 2x2 neighbourhood leaves the photo
        (COLMAP skips those observations).
    """
    h, w = rgb.shape[:2]
    xy = np.asarray(xy_px, np.float64).reshape(-1, 2) - 0.5
    x0, y0 = np.floor(xy[:, 0]), np.floor(xy[:, 1])
    valid = (x0 >= 0) & (y0 >= 0) & (x0 + 1 < w) & (y0 + 1 < h)
    xi, yi = x0[valid].astype(np.int64), y0[valid].astype(np.int64)
    fx, fy = (xy[valid, 0] - x0[valid])[:, None], (xy[valid, 1] - y0[valid])[:, None]
    # the 2x2 neighbours of each point: top-left, top-right, bottom-left, bottom-right
    c = rgb[np.stack([yi, yi, yi + 1, yi + 1], 1), np.stack([xi, xi + 1, xi, xi + 1], 1)].astype(np.float64)
    top = c[:, 0] * (1 - fx) + c[:, 1] * fx
    bottom = c[:, 2] * (1 - fx) + c[:, 3] * fx
    colors = np.zeros((len(xy), 3))
    colors[valid] = top * (1 - fy) + bottom * fy
    return colors, valid
