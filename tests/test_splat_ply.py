"""Official point_cloud.ply / cameras.json compatibility."""

from __future__ import annotations

import numpy as np
import pytest
from plyfile import PlyData, PlyElement

from gs2e.common.errors import InputError
from gs2e.splat.ply import read_cameras_json, read_ply, write_cameras_json, write_ply


def _random_model(n, degree, rng):
    k = (degree + 1) ** 2
    return dict(means=rng.normal(size=(n, 3)), quats=rng.normal(size=(n, 4)),
                log_scales=rng.normal(size=(n, 3)) - 3, opacity_logits=rng.normal(size=n),
                sh=rng.normal(size=(n, k, 3)))


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_round_trip(tmp_path, degree):
    m = _random_model(50, degree, np.random.default_rng(degree))
    write_ply(tmp_path / "p.ply", **m)
    back = read_ply(tmp_path / "p.ply")
    for k, v in m.items():
        np.testing.assert_allclose(back[k], v.astype(np.float32), rtol=0, atol=0)


def test_layout_matches_official_order(tmp_path):
    m = _random_model(3, 3, np.random.default_rng(0))
    write_ply(tmp_path / "p.ply", **m)
    ply = PlyData.read(str(tmp_path / "p.ply"))
    names = ply["vertex"].data.dtype.names
    assert names[:9] == ("x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2")
    assert names[9:54] == tuple(f"f_rest_{i}" for i in range(45))
    assert names[54:] == ("opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3")
    assert ply.byte_order == "<" and not ply.text
    # channel-major f_rest: f_rest_0..14 are the red channel's 15 coefficients
    v = ply["vertex"].data
    np.testing.assert_allclose([v[f"f_rest_{i}"][0] for i in range(15)], m["sh"][0, 1:, 0].astype(np.float32))
    np.testing.assert_allclose([v[f"f_rest_{15 + i}"][0] for i in range(15)], m["sh"][0, 1:, 1].astype(np.float32))


def _write_raw(path, names, n=4, value=0.5):
    arr = np.full(n, value, dtype=[(nm, "<f4") for nm in names])
    PlyData([PlyElement.describe(arr, "vertex")]).write(str(path))


def test_missing_attribute_is_named(tmp_path):
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2"]
    _write_raw(tmp_path / "m.ply", names)
    with pytest.raises(InputError, match=r"m\.ply.*rot_3"):
        read_ply(tmp_path / "m.ply")


def test_wrong_sh_count(tmp_path):
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", *[f"f_rest_{i}" for i in range(10)],
             "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    _write_raw(tmp_path / "m.ply", names)
    with pytest.raises(InputError, match="10 f_rest"):
        read_ply(tmp_path / "m.ply")


def test_nan_values_rejected(tmp_path):
    m = _random_model(5, 1, np.random.default_rng(0))
    write_ply(tmp_path / "p.ply", **m)
    ply = PlyData.read(str(tmp_path / "p.ply"), mmap=False)
    ply["vertex"].data["scale_1"][3] = np.nan
    ply.write(str(tmp_path / "p.ply"))
    with pytest.raises(InputError, match="vertex 3"):
        read_ply(tmp_path / "p.ply")
    m["means"][0, 0] = np.inf
    with pytest.raises(ValueError, match="means"):
        write_ply(tmp_path / "q.ply", **m)
    assert not (tmp_path / "q.ply").exists()


def test_corrupt_file(tmp_path):
    m = _random_model(100, 3, np.random.default_rng(0))
    write_ply(tmp_path / "p.ply", **m)
    data = (tmp_path / "p.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match=r"t\.ply"):
        read_ply(tmp_path / "t.ply")
    (tmp_path / "g.ply").write_bytes(b"not a ply at all")
    with pytest.raises(InputError, match=r"g\.ply"):
        read_ply(tmp_path / "g.ply")


def test_cameras_json_round_trip(tmp_path):
    from gs2e.common.so3 import quat_to_rotmat
    from gs2e.io.scene import Camera, Frame, Scene

    rng = np.random.default_rng(0)
    frames = []
    for i in range(3):
        T = np.eye(4)
        T[:3, :3] = quat_to_rotmat(rng.normal(size=4))
        T[:3, 3] = rng.normal(size=3)
        frames.append(Frame(f"im{i}.png", Camera(100 + i, 101 + i, 32, 24), T))
    write_cameras_json(tmp_path / "cameras.json", Scene(64, 48, frames))
    back = read_cameras_json(tmp_path / "cameras.json")
    assert [e["img_name"] for e in back] == ["im0", "im1", "im2"]
    for e, f in zip(back, frames):
        np.testing.assert_allclose(e["c2w"], f.c2w, atol=1e-12)
        assert e["fx"] == f.camera.fx and e["width"] == 64
