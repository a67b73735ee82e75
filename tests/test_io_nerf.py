"""transforms.json (NeRF / instant-ngp / nerfstudio) <-> Scene."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from _io_synth import make_scene, project, write_images, write_transforms_gl
from gs2e.common.errors import InputError
from gs2e.io.nerf import read_transforms, read_transforms_views, write_transforms
from gs2e.io.scene import Camera, Frame


def _gl_project(c2w_gl, fx, fy, cx, cy, W, H, X, near=0.01, far=100.0):
    """OpenGL pipeline: view matrix, projection matrix from intrinsics, NDC, viewport
    (window origin bottom-left), then flip to image rows (origin top-left)."""
    view = np.linalg.inv(c2w_gl)
    P = np.array([
        [2 * fx / W, 0, 1 - 2 * cx / W, 0],
        [0, 2 * fy / H, 2 * cy / H - 1, 0],
        [0, 0, -(far + near) / (far - near), -2 * far * near / (far - near)],
        [0, 0, -1, 0],
    ])
    clip = P @ view @ np.append(X, 1.0)
    ndc = clip[:3] / clip[3]
    assert -1 < ndc[2] < 1  # in front of the camera, inside the frustum depth range
    x_win = (ndc[0] + 1) / 2 * W
    y_win = (ndc[1] + 1) / 2 * H
    return np.array([x_win, H - y_win])


@pytest.mark.parametrize("cam", [
    Camera(40.0, 41.0, 24.3, 15.7, "OPENCV", [0.02, -0.003, 1e-3, -5e-4]),
    Camera(40.0, 40.0, 24.0, 16.0, "PINHOLE", []),
    Camera(40.0, 41.0, 24.3, 15.7, "OPENCV_FISHEYE", [0.02, -0.003, 1e-3, -5e-4]),
    Camera(40.0, 41.0, 24.3, 15.7, "FULL_OPENCV", [0.02, -0.003, 1e-3, -5e-4, 1e-4, 0, 0, 0]),
])
def test_roundtrip_global_intrinsics(tmp_path, cam):
    scene = make_scene(4, camera=cam, points=0)
    write_transforms(scene, tmp_path / "transforms.json")
    data = json.loads((tmp_path / "transforms.json").read_text())
    assert "fl_x" in data and "fl_x" not in data["frames"][0]
    back = read_transforms(tmp_path / "transforms.json")
    assert [f.name for f in back.frames] == ["images/" + f.name for f in scene.frames]
    assert (back.width, back.height) == (scene.width, scene.height)
    for a, b in zip(scene.frames, back.frames):
        assert b.camera == a.camera
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-15)


def test_roundtrip_per_frame_intrinsics(tmp_path):
    scene = make_scene(3, points=0)
    cams = [Camera(40.0 + i, 41.0 + i, 24.0, 16.0, "OPENCV", [0.01 * i, 0.0, 0.0, 0.001]) for i in range(3)]
    scene.frames = [Frame(f.name, c, f.c2w) for f, c in zip(scene.frames, cams)]
    write_transforms(scene, tmp_path / "t.json", image_prefix="./")
    data = json.loads((tmp_path / "t.json").read_text())
    assert "fl_x" not in data and data["frames"][2]["fl_x"] == 42.0
    back = read_transforms(tmp_path / "t.json")
    assert [f.name for f in back.frames] == [f.name for f in scene.frames]
    for a, b in zip(scene.frames, back.frames):
        assert b.camera == a.camera
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-15)


def test_simple_radial_written_as_equivalent_opencv(tmp_path):
    scene = make_scene(2, camera=Camera(40.0, 40.0, 24.0, 16.0, "SIMPLE_RADIAL", [0.05]), points=0)
    write_transforms(scene, tmp_path / "t.json")
    back = read_transforms(tmp_path / "t.json")
    assert back.frames[0].camera == Camera(40.0, 40.0, 24.0, 16.0, "OPENCV", [0.05, 0.0, 0.0, 0.0])


def test_projection_opengl_pose_equals_opencv_pose(tmp_path):
    """A world point projects to the same pixel through the NeRF (OpenGL) pose with
    OpenGL projection maths and through our OpenCV c2w with the pinhole model."""
    cam = Camera(60.0, 62.0, 31.0, 22.5, "PINHOLE", [])
    scene = make_scene(6, w=64, h=48, camera=cam, points=0)
    write_images(tmp_path, [f"r_{i}.png" for i in range(6)], 64, 48)
    # hand-written NeRF-synthetic style: camera_angle_x only, no w/h, no extension
    frames = []
    from gs2e.io.scene import opencv_to_opengl
    for i, f in enumerate(scene.frames):
        frames.append({"file_path": f"./r_{i}", "transform_matrix": opencv_to_opengl(f.c2w).tolist()})
    fov_x = 2 * math.atan(0.5 * 64 / 60.0)
    (tmp_path / "transforms_train.json").write_text(json.dumps({"camera_angle_x": fov_x, "frames": frames}))
    back = read_transforms(tmp_path / "transforms_train.json")
    assert (back.width, back.height) == (64, 48)  # from the first image
    rng = np.random.default_rng(3)
    for i, f in enumerate(back.frames):
        assert f.name == f"r_{i}"
        c = f.camera
        assert c.fx == pytest.approx(60.0, rel=1e-12) and c.fy == c.fx and (c.cx, c.cy) == (32.0, 24.0)
        gl = np.array(frames[i]["transform_matrix"])
        for X in rng.normal(scale=0.3, size=(5, 3)):
            uv_gl = _gl_project(gl, c.fx, c.fy, c.cx, c.cy, 64, 48, X)
            uv_cv = project(f.c2w, c, X)
            np.testing.assert_allclose(uv_cv, uv_gl, atol=1e-9)
        # and the point in front of the OpenCV camera has positive depth
        assert (np.linalg.inv(f.c2w) @ np.append(np.zeros(3), 1))[2] > 0


def test_applied_transform_is_undone(tmp_path):
    """nerfstudio's transform_matrix = A @ c2w_colmap; reading gives back c2w_colmap."""
    scene = make_scene(3, points=0)
    A = np.eye(4)[[0, 2, 1, 3]]
    A[2, :] *= -1
    write_transforms_gl(tmp_path / "transforms.json", scene, ["a.png", "b.png", "c.png"],
                        extra_top={"applied_transform": A[:3].tolist()}, transform_world=A)
    views = read_transforms_views(tmp_path / "transforms.json")
    for v, f in zip(views, scene.frames):
        np.testing.assert_allclose(v.c2w, f.c2w, atol=1e-14)
        assert v.camera == f.camera


@pytest.mark.parametrize("bad, match", [
    ({"frames": [{"file_path": "a.png", "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, float("nan")], [0, 0, 0, 1]]}]}, "NaN"),
    ({"frames": [{"file_path": "a.png", "transform_matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}]}, "rotation"),
    ({"frames": [{"file_path": "a.png"}]}, "transform_matrix"),
    ({"nope": 1}, "frames"),
    ({"camera_model": "EQUIRECTANGULAR", "frames": [{"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}, "EQUIRECTANGULAR"),
])
def test_bad_transforms(tmp_path, bad, match):
    base = {"w": 8, "h": 6, "fl_x": 10.0}
    p = tmp_path / "transforms.json"
    p.write_text(json.dumps({**base, **bad}))
    with pytest.raises(InputError, match=match) as ei:
        read_transforms(p)
    assert "transforms.json" in str(ei.value)


def test_unparsable_json_names_file(tmp_path):
    p = tmp_path / "transforms.json"
    p.write_text("{not json")
    with pytest.raises(InputError, match="transforms.json"):
        read_transforms(p)


def test_per_frame_intrinsics_of_mixed_orientations_without_sizes(tmp_path):
    """Per-frame fl_x/cx/cy, no w/h, three landscape and two portrait images:
    each frame's size comes from its own image (the first one's was applied to
    every frame: "b0.png is 60x80 but its camera is for 80x60")."""
    from _io_synth import ring_poses

    from gs2e.io.ingest import ingest_scene
    from gs2e.io.scene import opencv_to_opengl
    from gs2e.io.settings import IngestSettings

    src = tmp_path / "src"
    (src / "images").mkdir(parents=True)
    write_images(src / "images", ["a0.png", "a1.png", "a2.png"], 80, 60)
    write_images(src / "images", ["b0.png", "b1.png"], 60, 80, seed=1)
    frames = []
    for i, (name, c2w) in enumerate(zip(["a0", "a1", "a2", "b0", "b1"], ring_poses(5))):
        w, h = (80, 60) if name[0] == "a" else (60, 80)
        frames.append({"file_path": f"images/{name}.png", "transform_matrix": opencv_to_opengl(c2w).tolist(),
                       "fl_x": 70.0 + i, "fl_y": 70.0 + i, "cx": w / 2, "cy": h / 2})
    (src / "transforms.json").write_text(json.dumps({"frames": frames}))
    scene = read_transforms(src / "transforms.json")
    sizes = {f.name: (f.camera.cx * 2, f.camera.cy * 2) for f in scene.frames}
    assert sizes["images/b0.png"] == (60, 80) and sizes["images/a0.png"] == (80, 60)
    out = ingest_scene(src, "nerf", tmp_path / "ingest", IngestSettings.defaults(allow_mixed_resolutions=True))
    assert {(f.camera.cx * 2, f.camera.cy * 2) for f in out.frames} == {(80, 60), (60, 80)}
