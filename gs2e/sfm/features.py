"""SIFT features of one photo, in COLMAP's conventions, for its database.

Both extractors see the photo as gs2e decodes and shrinks it
(:func:`shrink_for_sift`: OpenCV's area filter), so the keypoints land in the
photo's own pixels whichever runs:

- :func:`colmap_sift_features`: COLMAP's own SIFT (VLFeat) on that array,
  through pycolmap. Decoding and shrinking here instead of in COLMAP's image
  reader saves that reader's CPU (it decodes and rescales each full-size
  photo beside the SIFT thread: about 0.3 CPU-s per 1920x1440 view), and lets
  the first octave follow the size SIFT sees (:func:`sift_first_octave`);
- :func:`sift_features`: OpenCV's SIMD SIFT, about a quarter of COLMAP's CPU
  at the same size, but its matches are fewer per view pair on mouse_colmap
  (a view at the edge of registering is lost more often), so
  ``sfm.extractor: opencv`` is an option, not the default (docs/sfm.md).

Conventions (those of COLMAP's extractor):

- keypoint centres in the photo's pixels, with the centre of the top-left
  pixel at (0.5, 0.5); scale (px) and orientation (rad) in columns 2 and 3
  (OpenCV's), or COLMAP's affine shape (a11, a12, a21, a22) in columns 2-5;
- descriptors L1-normalised, square-rooted (RootSIFT, COLMAP's ``L1_ROOT``)
  and stored as ``min(255, round(512 x))`` in uint8.
"""

from __future__ import annotations

import numpy as np

# OpenCV divides its contrast threshold by the layers per octave (3) and
# compares with the DoG of an image in [0, 1]: 0.02 / 3 is COLMAP's default
# peak threshold (0.02 / octave_resolution), half OpenCV's own default.
CONTRAST_THRESHOLD = 0.02


# sfm.max_image_size and sfm.sift_first_octave at auto (benchmarks/bench_sfm_size.py,
# mouse_colmap's photos as they are, shrunk and cropped, three mapper seeds each,
# one camera per view size; views registered, CPU-s of the whole gs2e sfm):
#   photo        800 px doubled          1024 px doubled     up to 2048 px, not doubled
#   1920x1440    56, 56, 56 of 56, 54-62                     56, 56, 56, 87-90
#   1920x1080    50, 50, 50 of 50, 44-53  50, 50, 50, 84-106
#   1440x1080    56, 56, 56 of 56, 50-54  56, 56, 56, 94-107
# (the last two columns verified with shared cameras, about 10 CPU-s more;
# 1920x1440: camera errors 0.38-0.51 deg and 5.3-5.4 % of the extent at 800 px,
# 0.45-0.51 deg and 5.4-5.6 % undoubled.) So every photo is seen at up to
# SIFT_AUTO_MAX_PX, doubled.
SIFT_AUTO_MAX_PX = 800
# sfm.sift_first_octave at auto doubles an image SIFT sees of up to this size
# (so an explicit sfm.max_image_size of 1024 px is doubled, 1600 px is not)
SIFT_DOUBLE_UP_TO_PX = 1024
SIFT_NATIVE_LIMIT_PX = 3200  # COLMAP's own cap on the image SIFT sees


def sift_side_px(max_image_size, photo_hw: tuple[int, int]) -> int:
    """Longer side (px) of the image SIFT sees of a photo of ``photo_hw``
    (height, width; either order) pixels: at most ``max_image_size`` (an int;
    None: the photo's own size up to COLMAP's 3200 px; ``"auto"``: up to
    :data:`SIFT_AUTO_MAX_PX`)."""
    h, w = (int(v) for v in photo_hw)
    if max_image_size == "auto":
        limit = SIFT_AUTO_MAX_PX
    else:
        limit = SIFT_NATIVE_LIMIT_PX if max_image_size is None else int(max_image_size)
    return min(max(h, w), limit)


def sift_first_octave(setting, side_px: int) -> int:
    """COLMAP's ``first_octave`` for an image whose longer side SIFT sees is
    ``side_px``: ``setting`` itself (-1 doubles the image, 0 does not), or for
    ``"auto"`` -1 up to :data:`SIFT_DOUBLE_UP_TO_PX` px and 0 beyond."""
    if setting == "auto":
        return -1 if side_px <= SIFT_DOUBLE_UP_TO_PX else 0
    return int(setting)


def shrink_for_sift(gray: np.ndarray, max_image_size) -> tuple[np.ndarray, float, float]:
    """The image SIFT sees of a photo: ``gray`` (H, W) uint8 shrunk with an
    area filter to the longer side :func:`sift_side_px` gives for
    ``max_image_size`` (unchanged when already that small), with the factors
    (sx, sy) that take its pixel coordinates back to the photo's."""
    import cv2

    h, w = gray.shape
    f = sift_side_px(max_image_size, (h, w)) / max(h, w)
    img = gray if f == 1.0 else cv2.resize(gray, (max(1, round(w * f)), max(1, round(h * f))),
                                           interpolation=cv2.INTER_AREA)
    return img, w / img.shape[1], h / img.shape[0]


def colmap_sift_features(gray: np.ndarray, max_image_size, max_num_features: int, first_octave="auto",
                         device=None) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP's SIFT of one photo, keypoints in the photo's pixels.

    Parameters
    ----------
    gray : (H, W) uint8 luminance of the photo.
    max_image_size : ``sfm.max_image_size``: an int (px), ``"auto"`` or None
        (:func:`sift_side_px`).
    max_num_features : keep at most this many keypoints (COLMAP's choice).
    first_octave : ``"auto"``, -1 or 0 (:func:`sift_first_octave`).
    device : a ``pycolmap.Device`` (None: the CPU).

    Returns
    -------
    keypoints : (N, 6) float32, x and y (px, pixel centres at +0.5) and the
        affine shape a11, a12, a21, a22, scaled to the photo's pixels as
        COLMAP's own extractor scales them.
    descriptors : (N, 128) uint8 RootSIFT in COLMAP's bytes.

    The same photo gives the same bytes on every call and thread (COLMAP's
    CPU SIFT on one thread; pycolmap holds the GIL while it runs).
    """
    import pycolmap

    img, sx, sy = shrink_for_sift(gray, max_image_size)
    device = pycolmap.Device.cpu if device is None else device
    opts = pycolmap.FeatureExtractionOptions()
    opts.num_threads = 1
    opts.use_gpu = device == pycolmap.Device.cuda
    opts.sift.max_num_features = int(max_num_features)
    opts.sift.first_octave = sift_first_octave(first_octave, max(img.shape))
    extractor = pycolmap.FeatureExtractor.create(opts, device)
    kps, desc = extractor.extract_from_uint8_array(np.ascontiguousarray(img))
    keypoints = np.array([(k.x, k.y, k.a11, k.a12, k.a21, k.a22) for k in kps], np.float32).reshape(-1, 6)
    # COLMAP's FeatureKeypoint::Rescale: x and the shape's first column by sx, y and its second by sy
    keypoints *= np.array([sx, sy, sx, sy, sx, sy], np.float32)
    return keypoints, np.asarray(desc.data, np.uint8).reshape(-1, 128)


def sift_features(gray: np.ndarray, max_image_size, max_num_features: int) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's SIFT of one photo, in COLMAP's conventions.

    Parameters
    ----------
    gray : (H, W) uint8 luminance of the photo.
    max_image_size : ``sfm.max_image_size``: an int (px), ``"auto"`` or None
        (:func:`sift_side_px`); the keypoints are scaled back to the photo's pixels.
    max_num_features : keep at most this many keypoints (strongest first).

    Returns
    -------
    keypoints : (N, 4) float32, x and y (px, pixel centres at +0.5), scale
        (px) and orientation (rad), in the photo's pixels.
    descriptors : (N, 128) uint8 RootSIFT, in COLMAP's byte scaling.

    The image is always doubled before the first octave (as COLMAP's
    first_octave -1; OpenCV has no other choice) with OpenCV's precise
    upscaling, which keeps keypoints in place. Call with OpenCV on one thread
    (``cv2.setNumThreads(1)``) for results that do not depend on thread timing.
    """
    import cv2

    img, sx, sy = shrink_for_sift(gray, max_image_size)
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
