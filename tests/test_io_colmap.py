"""COLMAP sparse models <-> Scene (pycolmap 4)."""

from __future__ import annotations

import numpy as np
import pycolmap
import pytest

from _io_synth import make_scene, project
from gs2e.common.errors import InputError
from gs2e.io.colmap import (read_colmap_model, reconstruction_from_scene, scene_from_reconstruction,
                            write_colmap_model)
from gs2e.io.scene import Camera, Frame

CAMERAS = [
    Camera(40.0, 40.0, 24.1, 15.9, "SIMPLE_PINHOLE", []),
    Camera(40.0, 41.5, 24.1, 15.9, "PINHOLE", []),
    Camera(40.0, 40.0, 24.1, 15.9, "SIMPLE_RADIAL", [0.03]),
    Camera(40.0, 40.0, 24.1, 15.9, "RADIAL", [0.03, -0.004]),
    Camera(40.0, 41.0, 24.1, 15.9, "OPENCV", [0.03, -0.004, 1e-3, -2e-3]),
    Camera(40.0, 41.0, 24.1, 15.9, "OPENCV_FISHEYE", [0.03, -0.004, 1e-3, -2e-4]),
    Camera(40.0, 41.0, 24.1, 15.9, "FULL_OPENCV", [0.03, -0.004, 1e-3, -2e-3, 1e-4, 0.01, -0.002, 3e-4]),
]


def _assert_same(a, b, names=True):
    if names:
        assert [f.name for f in a.frames] == [f.name for f in b.frames]
    assert (a.width, a.height) == (b.width, b.height)
    for fa, fb in zip(a.frames, b.frames):
        assert fa.camera == fb.camera, (fa.camera, fb.camera)
        np.testing.assert_allclose(fb.c2w, fa.c2w, atol=1e-12)
    np.testing.assert_array_equal(a.points_rgb, b.points_rgb)
    np.testing.assert_allclose(a.points_xyz, b.points_xyz, atol=0, rtol=0)


@pytest.mark.parametrize("binary", [True, False], ids=["bin", "txt"])
def test_roundtrip_all_models(tmp_path, binary):
    scene = make_scene(len(CAMERAS))
    scene.frames = [Frame(f.name, c, f.c2w) for f, c in zip(scene.frames, CAMERAS)]
    write_colmap_model(scene, tmp_path / "m", binary=binary)
    ext = "bin" if binary else "txt"
    assert (tmp_path / "m" / f"images.{ext}").is_file()
    back = read_colmap_model(tmp_path / "m")
    _assert_same(scene, back)
    assert back.source == str(tmp_path / "m")
    # the poses in the file are world-to-camera: COLMAP's own projection agrees with ours
    rec = pycolmap.Reconstruction(str(tmp_path / "m"))
    X = np.array([0.1, -0.2, 0.05])
    for image in rec.images.values():
        f = next(fr for fr in scene.frames if fr.name == image.name)
        if f.camera.model in ("SIMPLE_PINHOLE", "PINHOLE"):
            uv = image.project_point(X)
            np.testing.assert_allclose(uv, project(f.c2w, f.camera, X), atol=1e-9)


def test_reconstruction_api_shares_cameras_and_orders_by_name():
    names = ["img10.png", "img2.png", "img1.png"]
    scene = make_scene(3, names=names)
    rec = reconstruction_from_scene(scene)
    assert rec.num_cameras() == 1 and rec.num_images() == 3 and rec.num_reg_images() == 3
    assert rec.num_points3D() == len(scene.points_xyz)
    back = scene_from_reconstruction(rec)
    assert [f.name for f in back.frames] == ["img1.png", "img2.png", "img10.png"]
    by = {f.name: f for f in scene.frames}
    for f in back.frames:
        np.testing.assert_allclose(f.c2w, by[f.name].c2w, atol=1e-12)
        assert f.camera == by[f.name].camera
    # names= selects and orders; unknown names are skipped
    sub = scene_from_reconstruction(rec, names=["img2.png", "nope.png", "img10.png"])
    assert [f.name for f in sub.frames] == ["img2.png", "img10.png"]
    # distinct intrinsics -> distinct cameras
    scene.frames[1] = Frame(scene.frames[1].name, CAMERAS[1], scene.frames[1].c2w)
    assert reconstruction_from_scene(scene).num_cameras() == 2


def test_unregistered_images_are_skipped():
    scene = make_scene(3, points=0)
    scene.frames[1] = Frame(scene.frames[1].name, scene.frames[1].camera, None)
    rec = reconstruction_from_scene(scene)
    assert rec.num_images() == 3 and rec.num_reg_images() == 2
    back = scene_from_reconstruction(rec)
    assert [f.name for f in back.frames] == ["000.png", "002.png"]
    assert back.points_xyz is None


def test_bad_models(tmp_path):
    with pytest.raises(InputError, match="nothere"):
        read_colmap_model(tmp_path / "nothere")
    (tmp_path / "partial").mkdir()
    (tmp_path / "partial" / "cameras.bin").write_bytes(b"\0" * 8)
    with pytest.raises(InputError, match="partial"):
        read_colmap_model(tmp_path / "partial")
    scene = make_scene(3)
    write_colmap_model(scene, tmp_path / "c", binary=True)
    (tmp_path / "c" / "cameras.bin").write_bytes(b"garbage!")
    with pytest.raises(InputError, match=str(tmp_path / "c")):
        read_colmap_model(tmp_path / "c")
    # unparsable number in the text model: error names the model folder
    write_colmap_model(scene, tmp_path / "t", binary=False)
    txt = (tmp_path / "t" / "images.txt").read_text().splitlines()
    i = next(k for k, ln in enumerate(txt) if ln and not ln.startswith("#"))
    parts = txt[i].split()
    parts[5] = "x1e"
    txt[i] = " ".join(parts)
    (tmp_path / "t" / "images.txt").write_text("\n".join(txt) + "\n")
    with pytest.raises(InputError, match=str(tmp_path / "t")):
        read_colmap_model(tmp_path / "t")


def test_nan_pose_in_binary_model(tmp_path):
    rec = reconstruction_from_scene(make_scene(3))
    bad = np.hstack([np.eye(3), [[0.0], [np.nan], [1.0]]])
    img = rec.images[2]
    rec.frames[img.frame_id].rig_from_world = pycolmap.Rigid3d(bad)
    (tmp_path / "m").mkdir()
    rec.write(str(tmp_path / "m"))
    with pytest.raises(InputError, match=r"001\.png.*NaN"):
        read_colmap_model(tmp_path / "m")


def test_unsupported_camera_model(tmp_path):
    rec = pycolmap.Reconstruction()
    cam = pycolmap.Camera(model="FOV", width=40, height=30, params=[30, 30, 20, 15, 0.1], camera_id=1)
    rec.add_camera_with_trivial_rig(cam)
    rec.add_image_with_trivial_frame(pycolmap.Image(name="a.png", camera_id=1, image_id=1),
                                     pycolmap.Rigid3d())
    (tmp_path / "m").mkdir()
    rec.write(str(tmp_path / "m"))
    with pytest.raises(InputError, match="FOV"):
        read_colmap_model(tmp_path / "m")
