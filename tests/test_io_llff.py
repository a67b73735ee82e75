"""The llff and projection ingest layouts: LLFF's poses_bounds.npy and one
projection matrix per image (AliceVision cameras_P, Middlebury par files),
against poses known by construction and, where ../shared/data has them, a
capture's other cameras."""

from __future__ import annotations

import json

import numpy as np
import pytest

from _io_synth import ring_poses, write_images
from gs2e.common.errors import InputError
from gs2e.io.llff import decompose_projection, read_llff_views, read_projection_views
from tests.conftest import shared_data


def test_llff_rows_read_back_in_llffs_order(tmp_path):
    from gs2e.export.evdeblurnerf import llff_rows

    names = ["1.png", "10.png", "2.png", "3.png"]  # plain string order, as LLFF sorts
    write_images(tmp_path / "images", names, 40, 30)
    c2w = np.stack(ring_poses(4))
    np.save(tmp_path / "poses_bounds.npy", llff_rows(c2w, 60, 80, 70.0, np.tile([0.5, 9.0], (4, 1))))
    views, prov = read_llff_views(tmp_path)
    assert [v.name for v in views] == names
    assert np.abs(np.stack([v.c2w for v in views]) - c2w).max() < 1e-12
    assert views[0].size == (80, 60) and views[0].camera.fx == 70.0 and views[0].camera.cx == 40.0
    assert prov["near_far"] == [0.5, 9.0]


@pytest.mark.parametrize("rows,msg", [(np.zeros((3, 17)), "3 rows for 4 images"),
                                      (np.zeros((4, 15)), r"expected \(N, 17\)"),
                                      (np.full((4, 17), np.nan), r"expected \(N, 17\) finite")])
def test_llff_bad_arrays(tmp_path, rows, msg):
    write_images(tmp_path / "images", ["a.png", "b.png", "c.png", "d.png"], 40, 30)
    np.save(tmp_path / "poses_bounds.npy", rows)
    with pytest.raises(InputError, match=msg):
        read_llff_views(tmp_path)


def test_llff_equals_the_captures_colmap_model():
    """tumbler_cup_desk ships both: the same poses (in plain name order)."""
    src = shared_data("captures", "tumbler_cup_desk")
    from gs2e.io.ingest import _read_colmap

    a, _ = read_llff_views(src)
    b = {v.name: v for v in _read_colmap(src, {}).views}
    assert np.abs(np.stack([v.c2w for v in a]) - np.stack([b[v.name].c2w for v in a])).max() < 1e-9


@pytest.mark.parametrize("scale", [1.0, -3.5])
def test_projection_matrices_decompose_to_the_pose(scale):
    K = np.array([[500.0, 0.0, 320.0], [0.0, 510.0, 240.0], [0.0, 0.0, 1.0]])
    for c2w in ring_poses(5):
        w2c = np.linalg.inv(c2w)
        P = scale * K @ w2c[:3]
        K2, c2w2 = decompose_projection(P, "P")
        assert np.allclose(K2, K) and np.abs(c2w2 - c2w).max() < 1e-9


def test_alicevision_layout(tmp_path):
    names = ["00001._g.png", "00002._g.png", "00003._g.png"]
    write_images(tmp_path / "images", names, 80, 45)
    (tmp_path / "cameras_P").mkdir()
    (tmp_path / "mvs.ini").write_text("[global]\nwidth=320\nheight=180\nscale=2\n")
    K = np.array([[150.0, 0, 80.0], [0, 150.0, 45.0], [0, 0, 1]])
    poses = ring_poses(3)
    for n, c2w in zip(names, poses):
        np.savetxt(tmp_path / "cameras_P" / f"{n.split('.')[0]}_P.txt", K @ np.linalg.inv(c2w)[:3])
    views, prov = read_projection_views(tmp_path)
    assert [v.size for v in views] == [(160, 90)] * 3
    assert views[0].camera.cx == pytest.approx(80.5)  # OpenCV's (0, 0) centre -> gs2e's (0.5, 0.5)
    assert max(np.abs(v.c2w - p).max() for v, p in zip(views, poses)) < 1e-9
    (tmp_path / "cameras_P" / "00002_P.txt").unlink()
    with pytest.raises(InputError, match="00002_P.txt does not exist"):
        read_projection_views(tmp_path)


def test_middlebury_par_file_is_the_temple_ring_calibration():
    """Each view's pose is its line's R, t (camera centre -R^T t), whatever
    the line order (gs2e.testing.temple_c2w sorts them round the ring)."""
    from gs2e.testing import temple_c2w

    path = shared_data("temple_ring")
    views, _ = read_projection_views(path)
    assert len(views) == 47
    for ln in (path / "templeR_par.txt").read_text().splitlines()[1:]:
        v = np.array(ln.split()[1:], float)
        R, t = v[9:18].reshape(3, 3), v[18:21]
        view = next(x for x in views if x.name == ln.split()[0])
        assert np.abs(view.c2w[:3, :3] - R.T).max() < 1e-9 and np.abs(view.c2w[:3, 3] + R.T @ t).max() < 1e-9
        assert view.camera.fx == pytest.approx(v[0]) and view.camera.cx == pytest.approx(v[2] + 0.5)
    # the same set of cameras as the tests' ring
    got = np.sort(np.stack([x.c2w[:3, 3] for x in views]), axis=0)
    assert np.abs(got - np.sort(temple_c2w()[:, :3, 3], axis=0)).max() < 1e-9


def test_nerf_paths_of_a_flattened_copy(tmp_path):
    """kangaroo_plush's json names ./images/kangaroo/NAME.jpg; its files are images/NAME.jpg."""
    from _io_synth import make_scene, write_transforms_gl
    from gs2e.io.nerf import read_transforms

    scene = make_scene(3)
    write_images(tmp_path / "images", [f.name for f in scene.frames], scene.width, scene.height)
    write_transforms_gl(tmp_path / "transforms.json", scene,
                        [f"./images/capture/{f.name}" for f in scene.frames])
    got = read_transforms(tmp_path / "transforms.json")
    assert len(got.frames) == 3
    data = json.loads((tmp_path / "transforms.json").read_text())
    assert data["frames"][0]["file_path"].startswith("./images/capture/")
