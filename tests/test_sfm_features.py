"""OpenCV SIFT in COLMAP's conventions and OpenCV undistortion against COLMAP's
own: keypoints land in the photo's pixels whatever the size SIFT sees,
descriptors are COLMAP's RootSIFT bytes, undistorted views agree with
pycolmap's undistorter."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.sfm.features import (colmap_sift_features, root_sift_bytes, sift_features, sift_first_octave,
                               sift_side_px)
from gs2e.sfm.undistort import bilinear_colors, opencv_camera, undistort_image, undistortion_maps


def test_root_sift_bytes_is_colmaps_l1_root_scaling():
    rng = np.random.default_rng(0)
    d = rng.integers(0, 200, size=(5, 128)).astype(np.float32)
    d[1] = 0.0  # an empty descriptor stays empty
    d[2] = 0.0
    d[2, 7] = 3.0  # all mass in one bin: sqrt(1) * 512 saturates at 255
    b = root_sift_bytes(d)
    assert b.dtype == np.uint8 and b.shape == (5, 128)
    assert not b[1].any() and b[2, 7] == 255 and b[2].sum() == 255
    # the same descriptor at any scale gives the same bytes (L1 normalised first)
    assert np.array_equal(root_sift_bytes(d[[0]] * 7.5), b[[0]])
    # unit L2 norm before rounding: sum((b / 512)^2) = 1 up to rounding
    for row in (0, 3, 4):
        x = np.sqrt(d[row] / d[row].sum())
        assert np.array_equal(b[row], np.minimum(255, np.round(512 * x)).astype(np.uint8))
        assert abs(np.sum((b[row] / 512.0) ** 2) - 1.0) < 0.02


def _blob_image(w: int, h: int, centres, sigma: float) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    img = np.full((h, w), 40.0)
    for cx, cy in centres:  # pixel-index coordinates (OpenCV's)
        img += 180.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * sigma ** 2))
    return np.clip(np.round(img), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("max_side", [4000, 1000, 640])
def test_sift_keypoints_are_in_the_photos_pixels_at_any_sift_size(max_side):
    """Blobs at known places of a 2000x1500 photo: the strongest keypoint near
    each is within a quarter pixel of the blob centre in COLMAP's convention
    (centre of the top-left pixel at 0.5), whether SIFT sees the photo at its
    own size or shrunk 2x or 3.1x (keypoints scaled back)."""
    centres = [(401.25, 333.0), (1500.0, 1000.5), (987.0, 205.75)]
    img = _blob_image(2000, 1500, centres, sigma=12.0)
    kp, desc = sift_features(img, max_side, 8192)
    assert kp.dtype == np.float32 and kp.shape[1] == 4 and desc.shape == (len(kp), 128)
    for cx, cy in centres:
        d = np.hypot(kp[:, 0] - (cx + 0.5), kp[:, 1] - (cy + 0.5))
        assert d.min() < 0.25, (max_side, cx, cy, d.min())
        # a blob of sigma 12 px is found at a scale of that order, in photo pixels
        assert 4.0 < kp[np.argmin(d), 2] < 40.0


def test_sift_features_of_a_flat_image_are_empty_not_an_error():
    kp, desc = sift_features(np.full((300, 400), 128, np.uint8), 1024, 8192)
    assert kp.shape == (0, 4) and desc.shape == (0, 128) and desc.dtype == np.uint8


def test_sift_features_are_the_same_bytes_on_every_call():
    img = _blob_image(800, 600, [(200.0, 150.0), (600.0, 420.0)], sigma=6.0)
    rng = np.random.default_rng(1)
    img = np.clip(img.astype(int) + rng.integers(-20, 20, img.shape), 0, 255).astype(np.uint8)
    a, b = sift_features(img, 640, 500), sift_features(img, 640, 500)
    assert len(a[0]) > 50 and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


def test_sift_side_follows_the_photo_size_at_auto():
    """auto: every photo seen at up to 800 px (doubled); an int caps every
    photo, None only at COLMAP's 3200."""
    photos = [(480, 640), (520, 779), (768, 1024), (1080, 1920), (1920, 1080), (1440, 1920), (3024, 4032)]
    assert [sift_side_px("auto", hw) for hw in photos] == [640, 779, 800, 800, 800, 800, 800]
    assert [sift_side_px(1600, hw) for hw in ((480, 640), (1080, 1920))] == [640, 1600]
    assert [sift_side_px(None, hw) for hw in ((1080, 1920), (3000, 5000))] == [1920, 3200]
    # the first octave: doubled up to 1024 px, so auto never doubles past 2048
    assert [sift_first_octave("auto", s) for s in (640, 1024, 1025, 2048)] == [-1, -1, 0, 0]
    assert sift_first_octave(0, 640) == 0 and sift_first_octave(-1, 2048) == -1


@pytest.mark.parametrize("max_image_size,first_octave", [(4000, 0), (1000, -1), ("auto", "auto"), (640, "auto")])
def test_colmap_sift_keypoints_are_in_the_photos_pixels(max_image_size, first_octave):
    """COLMAP's SIFT on the image gs2e shrinks: blobs of a 2000x1500 photo are
    found within a quarter pixel of their centres in COLMAP's convention,
    whether SIFT sees the photo whole (doubled or not) or shrunk 2x to 3.1x,
    with the affine shape scaled back to the photo's pixels too."""
    centres = [(401.25, 333.0), (1500.0, 1000.5), (987.0, 205.75)]
    img = _blob_image(2000, 1500, centres, sigma=12.0)
    kp, desc = colmap_sift_features(img, max_image_size, 8192, first_octave)
    assert kp.dtype == np.float32 and kp.shape[1] == 6 and desc.shape == (len(kp), 128)
    assert desc.dtype == np.uint8
    for cx, cy in centres:
        d = np.hypot(kp[:, 0] - (cx + 0.5), kp[:, 1] - (cy + 0.5))
        assert d.min() < 0.25, (max_image_size, cx, cy, d.min())
        a11, a12, a21, a22 = kp[np.argmin(d), 2:]
        scale_px = np.sqrt(abs(a11 * a22 - a12 * a21))  # the shape's scale, photo pixels
        assert 4.0 < scale_px < 40.0


def test_colmap_sift_of_a_flat_image_is_empty_and_repeats_bytes():
    kp, desc = colmap_sift_features(np.full((300, 400), 128, np.uint8), "auto", 8192)
    assert kp.shape == (0, 6) and desc.shape == (0, 128)
    img = _blob_image(800, 600, [(200.0, 150.0), (600.0, 420.0)], sigma=6.0)
    rng = np.random.default_rng(1)
    img = np.clip(img.astype(int) + rng.integers(-20, 20, img.shape), 0, 255).astype(np.uint8)
    a, b = colmap_sift_features(img, 640, 500), colmap_sift_features(img, 640, 500)
    assert 50 < len(a[0]) <= 500 and np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])


@pytest.mark.parametrize("model,params", [
    ("SIMPLE_RADIAL", [700.0, 321.0, 239.5, -0.12]),
    ("RADIAL", [650.0, 318.5, 242.0, 0.08, -0.02]),
    ("OPENCV", [690.0, 672.0, 322.0, 236.0, -0.10, 0.03, 0.002, -0.0015]),
])
def test_opencv_undistortion_matches_colmaps(model, params):
    """A textured 640x480 photo undistorted by OpenCV through COLMAP's own
    undistorted camera agrees with pycolmap's undistorter: within 3 levels
    everywhere away from the border, 0.1 on average (bilinear both, OpenCV's
    weights in 1/32 px). A half-pixel slip of the principal point would give
    tens of levels on this texture."""
    pycolmap = pytest.importorskip("pycolmap")
    rng = np.random.default_rng(2)
    yy, xx = np.mgrid[0:480, 0:640]
    base = 128 + 60 * np.sin(xx / 5.0) * np.cos(yy / 7.0) + rng.normal(0, 3, (480, 640))
    rgb = np.clip(np.stack([base, base[::-1], 255 - base], axis=2), 0, 255).astype(np.uint8)
    cam = pycolmap.Camera(model=model, width=640, height=480, params=params)
    bitmap, ucam = pycolmap.undistort_image(pycolmap.UndistortCameraOptions(), pycolmap.Bitmap.from_array(rgb), cam)
    ref = bitmap.to_array()
    maps = undistortion_maps(model, params, ucam.params, (ucam.width, ucam.height))
    ours = undistort_image(rgb, maps)
    assert ours.shape == ref.shape
    diff = np.abs(ours.astype(int) - ref.astype(int))[4:-4, 4:-4]
    assert diff.max() <= 3 and diff.mean() < 0.1, (diff.max(), diff.mean())


def test_opencv_camera_moves_the_principal_point_half_a_pixel():
    K, dist = opencv_camera("SIMPLE_RADIAL", [500.0, 320.0, 240.0, 0.1])
    assert np.allclose(K, [[500, 0, 319.5], [0, 500, 239.5], [0, 0, 1]])
    assert np.allclose(dist, [0.1, 0, 0, 0, 0, 0, 0, 0])
    with pytest.raises(KeyError):
        opencv_camera("OPENCV_FISHEYE", [500.0, 500.0, 320.0, 240.0, 0, 0, 0, 0])


def test_bilinear_colors_use_colmaps_pixel_centres_and_skip_the_border():
    """A ramp photo: the colour at (x, y) in COLMAP's convention (pixel centres
    at +0.5) is the ramp's value at (x - 0.5, y - 0.5), exactly; points whose
    2x2 neighbourhood leaves the photo are not valid (COLMAP skips them)."""
    h, w = 6, 8
    yy, xx = np.mgrid[0:h, 0:w]
    rgb = np.stack([10 * xx, 20 * yy, 5 * xx + 7 * yy], axis=-1).astype(np.uint8)
    xy = np.array([[0.5, 0.5], [3.75, 2.25], [7.49, 5.49], [0.4, 3.0], [7.6, 3.0], [4.0, 5.6]])
    colors, valid = bilinear_colors(rgb, xy)
    assert valid.tolist() == [True, True, True, False, False, False]
    x, y = xy[valid, 0] - 0.5, xy[valid, 1] - 0.5
    assert np.allclose(colors[valid], np.stack([10 * x, 20 * y, 5 * x + 7 * y], axis=-1), atol=1e-9)
    assert not colors[~valid].any()
