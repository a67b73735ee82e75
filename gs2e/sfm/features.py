"""SIFT features with OpenCV, in COLMAP's conventions.

COLMAP's own CPU SIFT (VLFeat) took 1.3 s of CPU per 1024 px view on an AVX2
machine; OpenCV's SIMD SIFT finds keypoints of the same kind in about a
quarter of that (benchmarks/bench_sfm_size.py). The keypoints and
descriptors are written into COLMAP's feature database, so COLMAP's matcher
and mapper use them as they would their own. They match less well than
COLMAP's (fewer inliers per view pair on mouse_colmap: a view at the edge of
registering is lost more often), so ``sfm.extractor: opencv`` is an option,
not the default (docs/sfm.md).

Conventions (those of COLMAP's extractor):

- keypoint centres in the photo's pixels, with the centre of the top-left
  pixel at (0.5, 0.5); scale (px) and orientation (rad) in columns 2 and 3;
- descriptors L1-normalised, square-rooted (RootSIFT, COLMAP's ``L1_ROOT``)
  and stored as ``min(255, round(512 x))`` in uint8.
"""

from __future__ import annotations

import numpy as np

# OpenCV divides its contrast threshold by the layers per octave (3) and
# compares with the DoG of an image in [0, 1]: 0.02 / 3 is COLMAP's default
# peak threshold (0.02 / octave_resolution), half OpenCV's own default.
CONTRAST_THRESHOLD = 0.02


def sift_features(gray: np.ndarray, max_side: int, max_num_features: int) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints and RootSIFT descriptors of one photo.

    Parameters
    ----------
    gray : (H, W) uint8 luminance of the photo.
    max_side : longer side (px) of the image SIFT sees; a larger photo is
        shrunk (area filter) and the keypoints are scaled back to its pixels.
    max_num_features : keep at most this many keypoints (strongest first).

    Returns
    -------
    keypoints : (N, 4) float32, x and y (px, pixel centres at +0.5), scale
        (px) and orientation (rad), in the photo's pixels.
    descriptors : (N, 128) uint8 RootSIFT, in COLMAP's byte scaling.

    The image is doubled before the first octave (as COLMAP's first_octave
    -1) with OpenCV's precise upscaling, which keeps keypoints in place.
    Call with OpenCV on one thread (``cv2.setNumThreads(1)``) for results
    that do not depend on thread timing.
    """
    import cv2

    h, w = gray.shape
    f = min(1.0, max_side / max(h, w))
    img = gray if f == 1.0 else cv2.resize(gray, (max(1, round(w * f)), max(1, round(h * f))),
                                           interpolation=cv2.INTER_AREA)
    sx, sy = w / img.shape[1], h / img.shape[0]
    sift = cv2.SIFT_create(nfeatures=int(max_num_features), contrastThreshold=CONTRAST_THRESHOLD,
                           enable_precise_upscale=True)
    kps, desc = sift.detectAndCompute(img, None)
    if desc is None or not len(kps):
        return np.zeros((0, 4), np.float32), np.zeros((0, 128), np.uint8)
    pt = np.array([k.pt for k in kps], np.float64)
    size_px = np.array([k.size for k in kps], np.float64)
    # OpenCV's angle is in degrees, clockwise in image coordinates (y down)
    angle_rad = -np.deg2rad(np.array([k.angle for k in kps], np.float64))
    keypoints = np.column_stack([(pt[:, 0] + 0.5) * sx, (pt[:, 1] + 0.5) * sy,
                                 0.5 * size_px * np.sqrt(sx * sy), angle_rad]).astype(np.float32)
    return keypoints, root_sift_bytes(desc)


def root_sift_bytes(desc: np.ndarray) -> np.ndarray:
    """(N, 128) SIFT descriptors (any non-negative scale) as COLMAP stores
    them: L1-normalised, square-rooted (unit L2 norm), ``min(255, round(512 x))``
    in uint8. An all-zero descriptor stays zero."""
    d = np.asarray(desc, np.float64)
    l1 = d.sum(axis=1, keepdims=True)
    d = np.sqrt(d / np.where(l1 > 0, l1, 1.0))
    return np.minimum(255.0, np.round(512.0 * d)).astype(np.uint8)
