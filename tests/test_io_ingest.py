"""gs2e ingest: every layout on small synthetic fixtures, subsampling, downscaling,
bad input (error names the file, no output left), real data, the CLI."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from _io_synth import (DATA, make_scene, project, random_image, write_images, write_rgb,
                       write_transforms_gl)
from gs2e.io.settings import IngestSettings
from gs2e.common.errors import ConfigError, InputError
from gs2e.io.colmap import reconstruction_from_scene, write_colmap_model
from gs2e.io.images import encode_png, read_image
from gs2e.io.ingest import guess_camera, ingest_scene, subsample_indices, unique_png_names
from gs2e.io.scene import Camera, Frame, Scene, main_size, read_scene, write_scene_json

REPO = Path(__file__).resolve().parents[1]


def _colmap_project(root: Path, scene: Scene, binary=True, sparse="sparse/0", ext=".jpg", seed=0):
    """images/ + sparse model; images are JPG (lossy) or PNG."""
    names = [Path(f.name).with_suffix(ext).name for f in scene.frames]
    scene = Scene(scene.width, scene.height, [Frame(n, f.camera, f.c2w) for n, f in zip(names, scene.frames)],
                  points_xyz=scene.points_xyz, points_rgb=scene.points_rgb, extra=dict(scene.extra))
    imgs = write_images(root / "images", names, scene.width, scene.height, seed=seed)
    write_colmap_model(scene, root / sparse, binary=binary)
    return scene, imgs


def _assert_fails(src, layout, out, cfg, *must_name):
    with pytest.raises(InputError) as ei:
        ingest_scene(src, layout, out, IngestSettings.defaults(**cfg))
    msg = str(ei.value)
    for name in must_name:
        assert str(name) in msg, (name, msg)
    assert not Path(out).exists(), "partial output left behind"
    assert not any(p.name.startswith(f".{Path(out).name}.tmp") for p in Path(out).parent.iterdir())
    return msg


# ---------------------------------------------------------------- pure helpers

def test_subsample_indices():
    np.testing.assert_array_equal(subsample_indices(10, 4), [0, 3, 6, 9])
    np.testing.assert_array_equal(subsample_indices(5, None), np.arange(5))
    np.testing.assert_array_equal(subsample_indices(5, 9), np.arange(5))
    np.testing.assert_array_equal(subsample_indices(5, 2), [0, 4])
    for n in range(2, 120):
        for m in range(2, n + 1):
            idx = subsample_indices(n, m)
            assert len(idx) == m and idx[0] == 0 and idx[-1] == n - 1
            assert np.all(np.diff(idx) >= 1)
            # evenly spaced: gaps differ by at most 1
            assert np.diff(idx).max() - np.diff(idx).min() <= 1


def test_unique_png_names():
    assert unique_png_names(["a.jpg", "b.JPG", "c"]) == ["a.png", "b.png", "c.png"]
    out = unique_png_names(["x/a.jpg", "y/a.jpg", "a.png"])
    assert len(set(out)) == 3 and all(n.endswith(".png") for n in out)
    assert out == unique_png_names(["x/a.jpg", "y/a.jpg", "a.png"])  # deterministic


# ---------------------------------------------------------------- layouts

def test_folder_layout(tmp_path):
    src = tmp_path / "src"
    names = ["f1.png", "f10.png", "f2.jpg", "f3.png"]
    imgs = write_images(src, names, 40, 30)
    (src / "notes.txt").write_text("not an image")
    out = tmp_path / "out"
    scene = ingest_scene(src, "folder", out)
    assert [f.name for f in scene.frames] == ["f1.png", "f2.png", "f3.png", "f10.png"]
    assert scene.extra["intrinsics_guess"] is True and not scene.has_poses
    assert scene.frames[0].camera == Camera(48.0, 48.0, 20.0, 15.0, "PINHOLE", [])
    np.testing.assert_array_equal(read_image(out / "images" / "f1.png"), imgs["f1.png"])
    back = read_scene(out)
    assert back.extra["ingest"]["original_names"] == ["f1.png", "f2.jpg", "f3.png", "f10.png"]
    assert back.extra["ingest"]["layout"] == "folder"
    # src/images is found too, and the output is byte-identical on a second run
    (tmp_path / "src2").mkdir()
    os.rename(src, tmp_path / "src2" / "images")
    ingest_scene(tmp_path / "src2", "folder", tmp_path / "out2")
    for n in ["f1.png", "f2.png", "f3.png", "f10.png"]:
        assert (out / "images" / n).read_bytes() == (tmp_path / "out2" / "images" / n).read_bytes()


@pytest.mark.parametrize("binary, sparse", [(True, "sparse/0"), (False, "sparse/0"), (True, "sparse")],
                         ids=["bin", "txt", "sparse-direct"])
def test_colmap_layout(tmp_path, binary, sparse):
    ref, imgs = _colmap_project(tmp_path / "src", make_scene(5), binary, sparse)
    write_rgb(tmp_path / "src" / "images" / "zz_extra.jpg", random_image(np.random.default_rng(9), 48, 32))
    scene = ingest_scene(tmp_path / "src", "colmap", tmp_path / "out")
    assert [f.name for f in scene.frames] == [f"{i:03d}.png" for i in range(5)]
    for a, b in zip(ref.frames, scene.frames):
        assert b.camera == a.camera
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-12)
    back = read_scene(tmp_path / "out")
    np.testing.assert_allclose(back.points_xyz, ref.points_xyz, atol=0)
    np.testing.assert_array_equal(back.points_rgb, ref.points_rgb)
    assert back.extra["ingest"]["unregistered_images"] == ["zz_extra.jpg"]
    assert "sequential" not in back.extra
    # JPG pixels as decoded are what was written
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "images" / "000.png"),
                                  read_image(tmp_path / "src" / "images" / "000.jpg"))


def test_mvimgnet_layout_subsampled_and_downscaled(tmp_path):
    ref, _ = _colmap_project(tmp_path / "clip", make_scene(12, w=64, h=48))
    # MVImgNet models predate COLMAP's rigs/frames files
    for f in ("rigs.bin", "frames.bin"):
        (tmp_path / "clip" / "sparse" / "0" / f).unlink()
    cfg = IngestSettings.defaults(max_views=4, downscale=2)
    scene = ingest_scene(tmp_path / "clip", "mvimgnet", tmp_path / "out", cfg)
    assert scene.extra["sequential"] is True
    assert [f.name for f in scene.frames] == ["000.png", "004.png", "007.png", "011.png"]
    assert scene.extra["ingest"]["subsample_indices"] == [0, 4, 7, 11]
    assert (scene.width, scene.height) == (32, 24)
    assert read_image(tmp_path / "out" / "images" / "004.png").shape == (24, 32, 3)
    for f, i in zip(scene.frames, [0, 4, 7, 11]):
        assert f.camera == ref.frames[i].camera.scaled(0.5, 0.5)
        np.testing.assert_allclose(f.c2w, ref.frames[i].c2w, atol=1e-12)
        # a world point projects, through the ingested camera, to half its original pixel
        X = np.array([0.1, 0.2, -0.1])
        np.testing.assert_allclose(project(f.c2w, f.camera, X),
                                   0.5 * project(ref.frames[i].c2w, ref.frames[i].camera, X), atol=1e-9)
    assert scene.extra["ingest"]["scale_xy"] == [[0.5, 0.5]] * 4


def _dl3dv(root: Path, n=6, full=(96, 64), with_colmap=True):
    """DL3DV-like scene: transforms.json at full resolution (nerfstudio, with
    applied_transform) pointing to images/..., images_2/ and images_4/ on disk,
    colmap/sparse/0 with the original-world model."""
    ref = make_scene(n, w=full[0], h=full[1])
    names = [f"frame_{i + 1:05d}.png" for i in range(n)]
    ref.frames = [Frame(nm, f.camera, f.c2w) for nm, f in zip(names, ref.frames)]
    A = np.eye(4)[[0, 2, 1, 3]]
    A[2, :] *= -1
    write_transforms_gl(root / "transforms.json", ref, [f"images/{nm}" for nm in names],
                        extra_top={"applied_transform": A[:3].tolist()}, transform_world=A)
    for k in (2, 4):
        write_images(root / f"images_{k}", names, full[0] // k, full[1] // k, seed=k)
    if with_colmap:
        write_colmap_model(ref, root / "colmap" / "sparse" / "0")
    return ref


def test_dl3dv_layout(tmp_path):
    ref = _dl3dv(tmp_path / "scene")
    scene = ingest_scene(tmp_path / "scene", "dl3dv", tmp_path / "out")
    assert scene.extra["sequential"] is True
    assert scene.extra["ingest"]["images_subdir"] == "images_2"
    assert (scene.width, scene.height) == (48, 32)
    for a, b in zip(ref.frames, scene.frames):
        assert b.name == a.name
        assert b.camera == a.camera.scaled(0.5, 0.5)
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-12)  # applied_transform undone
    assert scene.extra["ingest"]["camera_scale_xy"][0] == [0.5, 0.5]
    info = scene.extra["ingest"]["colmap_points"]
    assert info["used"] and info["matched_cameras"] == 6 and abs(info["scale"] - 1) < 1e-9
    np.testing.assert_allclose(scene.points_xyz, ref.points_xyz, atol=1e-9)
    # explicit subfolder, and max_side picks the smallest folder still large enough
    s4 = ingest_scene(tmp_path / "scene", "dl3dv", tmp_path / "out4",
                      IngestSettings.defaults(images_subdir="images_4"))
    assert (s4.width, s4.height) == (24, 16) and s4.frames[0].camera == ref.frames[0].camera.scaled(0.25, 0.25)
    s20 = ingest_scene(tmp_path / "scene", "dl3dv", tmp_path / "out20", IngestSettings.defaults(max_side=20))
    assert s20.extra["ingest"]["images_subdir"] == "images_4" and (s20.width, s20.height) == (20, 13)
    with pytest.raises(ConfigError, match="images_subdir"):
        ingest_scene(tmp_path / "scene", "dl3dv", tmp_path / "out8",
                     IngestSettings.defaults(images_subdir="images_8"))
    assert not (tmp_path / "out8").exists()


def test_dl3dv_benchmark_layout_and_mismatched_colmap(tmp_path):
    """nerfstudio/ (json + images_N) and gaussian_splat/sparse/0 beside it; the
    COLMAP world may differ by a similarity (points follow); a model whose cameras
    do not match is ignored."""
    ref = _dl3dv(tmp_path / "s" / "nerfstudio", with_colmap=False)
    s, ang = 2.5, 0.7
    R = np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])
    t = np.array([0.3, -1.0, 2.0])
    S = np.eye(4)
    S[:3, :3], S[:3, 3] = R, t
    moved = Scene(ref.width, ref.height, [], points_xyz=s * ref.points_xyz @ R.T + t, points_rgb=ref.points_rgb)
    for f in ref.frames:  # world scaled by s, rotated, shifted
        T = S @ f.c2w
        T[:3, 3] = s * (R @ f.c2w[:3, 3]) + t
        moved.frames.append(Frame(f.name, f.camera, T))
    write_colmap_model(moved, tmp_path / "s" / "gaussian_splat" / "sparse" / "0")
    scene = ingest_scene(tmp_path / "s", "dl3dv", tmp_path / "out")
    info = scene.extra["ingest"]["colmap_points"]
    assert info["used"] and abs(info["scale"] - 1 / s) < 1e-9
    np.testing.assert_allclose(scene.points_xyz, ref.points_xyz, atol=1e-9)
    # shuffle the COLMAP cameras: no consistent similarity -> points dropped
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(moved.frames))
    moved.frames = [Frame(f.name, f.camera, moved.frames[j].c2w) for f, j in zip(moved.frames, perm)]
    write_colmap_model(moved, tmp_path / "s" / "gaussian_splat" / "sparse" / "0")
    scene = ingest_scene(tmp_path / "s", "dl3dv", tmp_path / "out")
    assert scene.points_xyz is None and not scene.extra["ingest"]["colmap_points"]["used"]


def test_nerf_layout_synthetic(tmp_path):
    """NeRF-synthetic style: transforms_train.json, camera_angle_x, './train/r_i'
    without extension, RGBA images (alpha dropped)."""
    ref = make_scene(4, w=40, h=40, camera=Camera(50.0, 50.0, 20.0, 20.0), points=0)
    rng = np.random.default_rng(5)
    frames = []
    from gs2e.io.scene import opencv_to_opengl
    for i, f in enumerate(ref.frames):
        rgba = np.dstack([random_image(rng, 40, 40), np.full((40, 40), 7, np.uint8)])
        (tmp_path / "src" / "train").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(tmp_path / "src" / "train" / f"r_{i}.png"), rgba[:, :, [2, 1, 0, 3]])
        frames.append({"file_path": f"./train/r_{i}", "transform_matrix": opencv_to_opengl(f.c2w).tolist()})
    (tmp_path / "src" / "transforms_train.json").write_text(json.dumps(
        {"camera_angle_x": 2 * np.arctan(20 / 50.0), "frames": frames}))
    scene = ingest_scene(tmp_path / "src", "nerf", tmp_path / "out")
    assert [f.name for f in scene.frames] == [f"r_{i}.png" for i in range(4)]
    for a, b in zip(ref.frames, scene.frames):
        assert b.camera.fx == pytest.approx(50.0, rel=1e-12) and (b.camera.cx, b.camera.cy) == (20.0, 20.0)
        np.testing.assert_allclose(b.c2w, a.c2w, atol=1e-14)
    assert read_image(tmp_path / "out" / "images" / "r_0.png").shape == (40, 40, 3)


@pytest.mark.parametrize("layout", ["internal", "demo"])
def test_internal_layout(tmp_path, layout):
    ref = make_scene(5, w=64, h=48)
    ref.extra = {"sequential": True, "ground_truth": "orbit"}
    (tmp_path / "src" / "images").mkdir(parents=True)
    write_images(tmp_path / "src" / "images", [f.name for f in ref.frames], 64, 48)
    write_scene_json(ref, tmp_path / "src")
    scene = ingest_scene(tmp_path / "src", layout, tmp_path / "out", IngestSettings.defaults(max_side=32))
    assert (scene.width, scene.height) == (32, 24)
    assert scene.extra["ground_truth"] == "orbit" and scene.extra["sequential"] is True
    for a, b in zip(ref.frames, scene.frames):
        assert b.camera == a.camera.scaled(0.5, 0.5)
    np.testing.assert_array_equal(read_scene(tmp_path / "out").points_xyz, ref.points_xyz)
    # re-ingesting an ingested scene with defaults changes nothing but provenance
    again = ingest_scene(tmp_path / "out", "internal", tmp_path / "out2")
    assert [f.camera for f in again.frames] == [f.camera for f in scene.frames]
    for n in (f.name for f in scene.frames):
        assert (tmp_path / "out" / "images" / n).read_bytes() == (tmp_path / "out2" / "images" / n).read_bytes()


def test_mixed_resolutions_allowed_keep_their_own_size(tmp_path):
    """A view of another resolution (not a rotation) needs the flag, and then
    keeps its size and its own intrinsics: no view is resampled to another's grid."""
    cam = Camera(40.0, 41.0, 24.2, 15.8, "PINHOLE", [])
    ref = make_scene(3, camera=cam)
    big = cam.scaled(2.0, 2.0)
    ref.frames[1] = Frame(ref.frames[1].name, big, ref.frames[1].c2w)
    ref.extra["frame_sizes"] = [[48, 32], [96, 64], [48, 32]]
    scene_src, _ = _colmap_project(tmp_path / "src", ref, ext=".png")
    write_images(tmp_path / "src" / "images", ["001.png"], 96, 64, seed=11)
    _assert_fails(tmp_path / "src", "colmap", tmp_path / "out", {}, "001.png", "96x64", "000.png")
    scene = ingest_scene(tmp_path / "src", "colmap", tmp_path / "out",
                         IngestSettings.defaults(allow_mixed_resolutions=True))
    assert (scene.width, scene.height) == (48, 32)  # the most common size
    assert [f.camera for f in scene.frames] == [cam, big, cam]
    assert read_image(tmp_path / "out" / "images" / "001.png").shape == (64, 96, 3)
    again = read_scene(tmp_path / "out")
    assert [again.frame_size(i) for i in range(3)] == [(48, 32), (96, 64), (48, 32)]
    assert scene.extra["ingest"]["scale_xy"][1] == [1.0, 1.0]
    # max_side caps each view's longer side: 96x64 -> 72x48 (scale 0.75), 48x32 untouched
    capped = ingest_scene(tmp_path / "src", "colmap", tmp_path / "capped",
                          IngestSettings.defaults(allow_mixed_resolutions=True, max_side=72))
    assert [capped.frame_size(i) for i in range(3)] == [(48, 32), (72, 48), (48, 32)]
    assert capped.frames[1].camera == big.scaled(0.75, 0.75)


@pytest.mark.parametrize("layout", ["colmap", "mvimgnet"])
def test_mixed_orientation_views_keep_their_orientation(tmp_path, layout):
    """A phone capture: landscape and portrait views of one lens, one camera per
    image. Each view keeps its orientation and intrinsics (no flag needed); the
    scene's size, the virtual trajectories' camera, is the most common one;
    the written COLMAP model round-trips every camera at its own size."""
    from gs2e.io.colmap import reconstruction_from_scene, scene_from_reconstruction

    land = Camera(50.0, 50.0, 24.0, 16.0, "PINHOLE", [])
    port = Camera(50.0, 50.0, 16.0, 24.0, "PINHOLE", [])
    ref = make_scene(5, camera=land)
    for i in (1, 3):
        ref.frames[i] = Frame(ref.frames[i].name, port, ref.frames[i].c2w)
    sizes = [[48, 32], [32, 48], [48, 32], [32, 48], [48, 32]]
    ref.extra["frame_sizes"] = sizes
    _colmap_project(tmp_path / "src", ref, ext=".png")
    for i in (1, 3):
        write_images(tmp_path / "src" / "images", [ref.frames[i].name], 32, 48, seed=20 + i)
    scene = ingest_scene(tmp_path / "src", layout, tmp_path / "out")
    assert (scene.width, scene.height) == (48, 32) and scene.main_frames() == [0, 2, 4]
    assert [list(scene.frame_size(i)) for i in range(5)] == sizes
    assert [f.camera for f in scene.frames] == [land, port, land, port, land]
    for i, f in enumerate(scene.frames):
        w, h = scene.frame_size(i)
        assert read_image(tmp_path / "out" / "images" / f.name).shape == (h, w, 3)
    back = scene_from_reconstruction(reconstruction_from_scene(scene))
    assert [back.frame_size(i) for i in range(5)] == [scene.frame_size(i) for i in range(5)]
    assert [f.camera for f in back.frames] == [f.camera for f in scene.frames]
    # a portrait majority makes the scene portrait
    assert main_size([(48, 32), (32, 48), (32, 48)]) == (32, 48)
    assert main_size([(48, 32), (32, 48)]) == (48, 32)  # a tie: the first seen


# ---------------------------------------------------------------- bad input

def test_missing_image_referenced_by_model(tmp_path):
    _colmap_project(tmp_path / "src", make_scene(4))
    (tmp_path / "src" / "images" / "002.jpg").unlink()
    _assert_fails(tmp_path / "src", "colmap", tmp_path / "out", {}, "002.jpg")


@pytest.mark.parametrize("damage", ["truncated", "empty", "garbage"])
def test_corrupt_image(tmp_path, damage):
    src = tmp_path / "src"
    write_images(src, ["a.png", "b.png", "c.png"], 32, 24)
    p = src / "b.png"
    data = p.read_bytes()
    p.write_bytes({"truncated": data[: len(data) // 2], "empty": b"", "garbage": b"\x89PNG garbage"}[damage])
    _assert_fails(src, "folder", tmp_path / "out", {}, str(p))


def test_unreadable_image(tmp_path):
    if os.geteuid() == 0:
        pytest.skip("running as root: file permissions do not stop reads")
    src = tmp_path / "src"
    write_images(src, ["a.png", "b.png"], 32, 24)
    (src / "b.png").chmod(0)
    _assert_fails(src, "folder", tmp_path / "out", {}, "b.png")


def test_duplicate_views_name_both_files(tmp_path):
    src = tmp_path / "src"
    imgs = write_images(src, ["a.png", "b.png", "c.png"], 32, 24)
    (src / "c.png").write_bytes((src / "a.png").read_bytes())  # byte-identical
    _assert_fails(src, "folder", tmp_path / "out", {}, "a.png", "c.png")
    # pixel-identical with different bytes (JPEG-free: PNG at another compression level)
    ok, buf = cv2.imencode(".png", imgs["a.png"][:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 9])
    (src / "c.png").write_bytes(buf.tobytes())
    assert (src / "c.png").read_bytes() != (src / "a.png").read_bytes()
    _assert_fails(src, "folder", tmp_path / "out", {}, "a.png", "c.png")


def test_mixed_resolution_folder(tmp_path):
    src = tmp_path / "src"
    write_images(src, ["a.png", "b.png"], 32, 24)
    write_images(src, ["c.png"], 30, 24)
    _assert_fails(src, "folder", tmp_path / "out", {}, "c.png", "30x24")
    scene = ingest_scene(src, "folder", tmp_path / "out", IngestSettings.defaults(allow_mixed_resolutions=True))
    assert read_image(tmp_path / "out" / "images" / "c.png").shape == (24, 30, 3)
    assert scene.frames[2].camera == guess_camera(30, 24)  # each view's own guess
    # a rotated view is no mixed resolution
    write_images(src, ["c.png"], 24, 32)
    rot = ingest_scene(src, "folder", tmp_path / "rot")
    assert [rot.frame_size(i) for i in range(3)] == [(32, 24), (32, 24), (24, 32)]


def test_nan_pose(tmp_path):
    ref = make_scene(3, points=0)
    write_images(tmp_path / "src", ["a.png", "b.png", "c.png"], 48, 32)
    write_transforms_gl(tmp_path / "src" / "transforms.json", ref, ["a.png", "b.png", "c.png"])
    data = json.loads((tmp_path / "src" / "transforms.json").read_text())
    data["frames"][1]["transform_matrix"][0][3] = float("nan")
    (tmp_path / "src" / "transforms.json").write_text(json.dumps(data))
    _assert_fails(tmp_path / "src", "nerf", tmp_path / "out", {}, "transforms.json", "b.png")


def test_nan_pose_internal(tmp_path):
    ref = make_scene(3, points=0)
    (tmp_path / "src" / "images").mkdir(parents=True)
    write_images(tmp_path / "src" / "images", [f.name for f in ref.frames], 48, 32)
    write_scene_json(ref, tmp_path / "src")
    data = json.loads((tmp_path / "src" / "scene.json").read_text())
    data["frames"][2]["c2w"][1][1] = float("nan")
    (tmp_path / "src" / "scene.json").write_text(json.dumps(data))
    _assert_fails(tmp_path / "src", "internal", tmp_path / "out", {}, "scene.json", "002.png", "NaN")
    del data["frames"][0]["camera"]
    (tmp_path / "src" / "scene.json").write_text(json.dumps(data))
    _assert_fails(tmp_path / "src", "internal", tmp_path / "out", {}, "scene.json")


def test_too_few_views(tmp_path):
    write_images(tmp_path / "src", ["only.png"], 32, 24)
    _assert_fails(tmp_path / "src", "folder", tmp_path / "out", {}, str(tmp_path / "src"))
    (tmp_path / "empty").mkdir()
    _assert_fails(tmp_path / "empty", "folder", tmp_path / "out", {}, str(tmp_path / "empty"))
    _assert_fails(tmp_path / "nowhere", "colmap", tmp_path / "out", {}, "nowhere")
    _assert_fails(tmp_path / "empty", "colmap", tmp_path / "out", {}, "sparse")


def test_failure_keeps_previous_output(tmp_path):
    src = tmp_path / "src"
    write_images(src, ["a.png", "b.png"], 32, 24)
    out = tmp_path / "out"
    ingest_scene(src, "folder", out)
    before = (out / "scene.json").read_bytes()
    (src / "b.png").write_bytes(b"")
    with pytest.raises(InputError, match="b.png"):
        ingest_scene(src, "folder", out)
    assert (out / "scene.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "src"]


def test_bad_config(tmp_path):
    write_images(tmp_path / "src", ["a.png", "b.png"], 32, 24)
    with pytest.raises(ConfigError, match="max_views"):
        ingest_scene(tmp_path / "src", "folder", tmp_path / "out", IngestSettings.defaults(max_views=1))
    with pytest.raises(ConfigError, match="bogus"):
        ingest_scene(tmp_path / "src", "folder", tmp_path / "out", IngestSettings.defaults(bogus=1))
    with pytest.raises(InputError, match="source"):
        ingest_scene(tmp_path / "src", "folder", tmp_path / "src" / "out")
    assert not (tmp_path / "out").exists()


# ---------------------------------------------------------------- real data

@pytest.mark.parametrize("name, n, size, glob", [
    ("llff_fern", 20, (706, 529), "images"),
    ("temple_ring", 47, (640, 480), ""),
])
def test_real_folders(tmp_path, name, n, size, glob):
    src = DATA / name
    if not src.is_dir():
        pytest.skip(f"real data {src} is absent")
    scene = ingest_scene(src, "folder", tmp_path / "out")
    assert len(scene.frames) == n and (scene.width, scene.height) == size
    files = sorted((src / glob).glob("*.png"))
    assert [f.name for f in scene.frames] == [p.name for p in files]
    np.testing.assert_array_equal(read_image(tmp_path / "out" / "images" / files[3].name),
                                  cv2.imread(str(files[3]))[:, :, ::-1])
    small = ingest_scene(src, "folder", tmp_path / "small", IngestSettings.defaults(max_views=10, max_side=200))
    assert len(small.frames) == 10 and max(small.width, small.height) == 200
    assert small.frames[0].name == files[0].name and small.frames[-1].name == files[-1].name


# ---------------------------------------------------------------- CLI

def _cli(*args, cwd=None):
    env = dict(os.environ, PYTHONPATH=str(REPO), GS2E_PROGRESS="0")
    return subprocess.run([sys.executable, "-m", "gs2e", "ingest", *args], capture_output=True,
                          text=True, env=env, cwd=cwd, timeout=120)


def test_cli_end_to_end(tmp_path):
    src = tmp_path / "src"
    write_images(src, ["a.png", "b.png", "c.png"], 32, 24)
    r = _cli("--layout", "folder", "--src", str(src), "--out", str(tmp_path / "out"),
             "--config-json", '{"max_views": 2}')
    assert r.returncode == 0, r.stderr
    assert [f.name for f in read_scene(tmp_path / "out").frames] == ["a.png", "c.png"]
    assert "ingest 2 images" in r.stderr and "done in" in r.stderr
    # bad input: exit 2, one error line naming the file, no output
    (src / "c.png").write_bytes(b"junk")
    r = _cli("--layout", "folder", "--src", str(src), "--out", str(tmp_path / "bad"))
    assert r.returncode == 2
    err = [ln for ln in r.stderr.splitlines() if ln.startswith("gs2e ingest: error:")]
    assert len(err) == 1 and str(src / "c.png") in err[0]
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "bad").exists()
    # bad config: exit 2 naming the key
    r = _cli("--layout", "folder", "--src", str(src), "--out", str(tmp_path / "bad"),
             "--config-json", '{"downscale": 0}')
    assert r.returncode == 2 and "downscale" in r.stderr.splitlines()[-1]
    r = _cli("--help")
    assert r.returncode == 0 and "--layout" in r.stdout and "dl3dv" in r.stdout
