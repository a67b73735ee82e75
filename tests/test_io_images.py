"""Image reading/writing, resizing and the intrinsics that go with it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from _io_synth import look_at_c2w, project
from gs2e.common.errors import InputError
from gs2e.io.images import (encode_png, read_image, resize_with_camera, scaled_size,
                            write_png)
from gs2e.io.scene import Camera


def test_read_png_jpg_roundtrip(tmp_path):
    rng = np.random.default_rng(1)
    img = rng.integers(0, 256, (17, 23, 3), dtype=np.uint8)
    write_png(tmp_path / "a.png", img)
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), img)
    # PNG bytes are a function of the pixels only
    assert encode_png(img) == (tmp_path / "a.png").read_bytes()
    assert encode_png(img.copy()) == encode_png(img)
    # channel order: a pure red image stays red through cv2's BGR world
    red = np.zeros((4, 5, 3), np.uint8)
    red[..., 0] = 255
    cv2.imwrite(str(tmp_path / "r.jpg"), red[:, :, ::-1])
    got = read_image(tmp_path / "r.jpg")
    assert got.shape == (4, 5, 3) and got[..., 0].min() > 240 and got[..., 2].max() < 15


def test_16bit_gray_alpha(tmp_path):
    v16 = np.array([[0, 257, 65535, 32896, 128, 129]], np.uint16)  # 32896 = 128*257
    cv2.imwrite(str(tmp_path / "g16.png"), v16)
    got = read_image(tmp_path / "g16.png")
    assert got.shape == (1, 6, 3) and got.dtype == np.uint8
    np.testing.assert_array_equal(got[0, :, 0], [0, 1, 255, 128, 0, 1])
    assert np.all(got[..., 0] == got[..., 2])
    # 16-bit colour keeps channel order
    c16 = np.zeros((2, 2, 3), np.uint16)
    c16[..., 2] = 65535  # BGR -> red channel
    cv2.imwrite(str(tmp_path / "c16.png"), c16)
    got = read_image(tmp_path / "c16.png")
    assert np.all(got[..., 0] == 255) and np.all(got[..., 1:] == 0)
    # alpha dropped, colour kept
    bgra = np.zeros((3, 3, 4), np.uint8)
    bgra[..., 1] = 200
    bgra[..., 3] = 0
    cv2.imwrite(str(tmp_path / "a.png"), bgra)
    got = read_image(tmp_path / "a.png")
    assert got.shape == (3, 3, 3) and np.all(got[..., 1] == 200) and np.all(got[..., [0, 2]] == 0)


@pytest.mark.parametrize("kind", ["missing", "empty", "truncated_png", "truncated_jpg", "text", "dir"])
def test_bad_image_files_name_the_file(tmp_path, kind):
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    p = tmp_path / f"bad_{kind}.png"
    if kind == "empty":
        p.write_bytes(b"")
    elif kind == "truncated_png":
        data = encode_png(img)
        p.write_bytes(data[: len(data) // 2])
    elif kind == "truncated_jpg":
        p = tmp_path / "bad_trunc.jpg"
        ok, buf = cv2.imencode(".jpg", img)
        p.write_bytes(buf.tobytes()[: len(buf) // 2])
    elif kind == "text":
        p.write_text("not an image at all")
    elif kind == "dir":
        p.mkdir()
    with pytest.raises(InputError, match=p.name):
        read_image(p)


def test_scaled_size():
    assert scaled_size(640, 480) == (640, 480)
    assert scaled_size(640, 480, 2) == (320, 240)
    assert scaled_size(641, 481, 2) == (321, 241)  # rounds half up
    assert scaled_size(640, 480, 1, 320) == (320, 240)
    assert scaled_size(480, 640, 1, 100) == (75, 100)
    assert scaled_size(640, 480, 2, 1000) == (320, 240)
    assert scaled_size(1000, 3, 1, 16) == (16, 1)


def _blob_image(w, h, u, v, sigma):
    x = np.arange(w) + 0.5  # pixel centres at +0.5
    y = np.arange(h) + 0.5
    g = np.exp(-((x[None, :] - u) ** 2 + (y[:, None] - v) ** 2) / (2 * sigma ** 2))
    return np.repeat(np.rint(255 * g).astype(np.uint8)[:, :, None], 3, axis=2)


def _centroid(img):
    I = img[..., 0].astype(np.float64)
    y, x = np.mgrid[: I.shape[0], : I.shape[1]] + 0.5
    return np.array([(I * x).sum() / I.sum(), (I * y).sum() / I.sum()])


@pytest.mark.parametrize("size", [(100, 75), (157, 118), (64, 64)])
def test_downscale_keeps_projection(size):
    """A 3D point drawn at its projection in a 400x300 image lands, after the
    area resize, at its projection through the scaled intrinsics. The error
    bound (0.03 px) is far below the 0.5*(1-s) px offset a wrong pixel-centre
    convention would give."""
    W, H = 400, 300
    cam = Camera(350.0, 360.0, 203.7, 148.2)
    c2w = look_at_c2w(np.array([2.0, -3.0, 1.0]))
    X = np.array([0.21, -0.13, 0.08])
    u, v = project(c2w, cam, X)
    img = _blob_image(W, H, u, v, sigma=9.0)
    np.testing.assert_allclose(_centroid(img), [u, v], atol=0.01)
    small, cam_s, (sx, sy) = resize_with_camera(img, cam, size)
    assert small.shape == (size[1], size[0], 3)
    assert (sx, sy) == (size[0] / W, size[1] / H)
    expect = project(c2w, cam_s, X)
    err = np.abs(_centroid(small) - expect).max()
    assert err < 0.03, (err, _centroid(small), expect)
    wrong_offset = 0.5 * (1 - min(sx, sy))
    assert wrong_offset > 5 * 0.03
