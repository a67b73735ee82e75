"""Official point_cloud.ply / cameras.json layout: round trips, foreign files, bad input."""

import json

import numpy as np
import pytest
import torch
from plyfile import PlyData, PlyElement

from gs2e.common.errors import InputError
from gs2e.splat.io import (CameraEntry, Gaussians, cameras_from_scene, latest_point_cloud,
                           ply_property_names, point_cloud_path, read_cameras_json, read_ply,
                           write_cameras_json, write_ply)
from gs2e.splat.rasterize import rasterize


def _model(n=50, K=16, seed=0):
    rng = np.random.default_rng(seed)
    return Gaussians(rng.normal(size=(n, 3)), rng.normal(size=(n, 4)), rng.normal(-3, 1, (n, 3)),
                     rng.normal(size=n), rng.normal(size=(n, K, 3)))


@pytest.mark.parametrize("K", [1, 4, 9, 16])
def test_ply_round_trip(tmp_path, K):
    g = _model(K=K)
    p = point_cloud_path(tmp_path / "model", 7000)
    write_ply(p, g)
    back = read_ply(p)
    assert back.sh_degree == g.sh_degree and back.n == g.n
    for k in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert np.array_equal(getattr(back, k), getattr(g, k).astype(np.float32)), k
    assert latest_point_cloud(tmp_path / "model") == (p, 7000)
    assert not [f for f in p.parent.iterdir() if f.name != "point_cloud.ply"]  # no temp files


def test_ply_header_is_the_official_layout(tmp_path):
    g = _model(n=3)
    write_ply(tmp_path / "m.ply", g)
    raw = (tmp_path / "m.ply").read_bytes()
    header = raw[:raw.index(b"end_header")].decode()
    assert "format binary_little_endian 1.0" in header
    assert "element vertex 3" in header
    props = [ln.split()[-1] for ln in header.splitlines() if ln.startswith("property")]
    assert all(ln.split()[1] == "float" for ln in header.splitlines() if ln.startswith("property"))
    assert props == ply_property_names(3) and len(props) == 62
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[-8:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    # f_rest is channel-major: f_rest_0..14 are red coefficients 1..15, 15..29 green
    v = PlyData.read(str(tmp_path / "m.ply"))["vertex"].data
    assert np.float32(v["f_rest_1"][0]) == np.float32(g.sh[0, 2, 0])
    assert np.float32(v["f_rest_16"][0]) == np.float32(g.sh[0, 2, 1])
    assert np.float32(v["f_rest_44"][0]) == np.float32(g.sh[0, 15, 2])


def _foreign_ply(path, n=20, K=4, drop=(), extra=True, nan_in=None, dtype="f4"):
    """A PLY as another tool writes it: no normals, extra attributes, custom order."""
    rng = np.random.default_rng(1)
    names = (["x", "y", "z", "opacity"] + [f"rot_{i}" for i in range(4)]
             + [f"scale_{i}" for i in range(3)] + [f"f_dc_{i}" for i in range(3)]
             + [f"f_rest_{i}" for i in range(3 * (K - 1))] + (["confidence"] if extra else []))
    names = [nm for nm in names if nm not in drop]
    arr = np.empty(n, dtype=[(nm, dtype) for nm in names])
    for nm in names:
        arr[nm] = rng.normal(size=n)
    if nan_in:
        arr[nan_in][3] = np.nan
    PlyData([PlyElement.describe(arr, "vertex")], text=False).write(str(path))
    return arr


def test_reads_files_from_other_writers(tmp_path):
    arr = _foreign_ply(tmp_path / "f.ply", dtype="f8")
    g = read_ply(tmp_path / "f.ply", dtype=np.float64)
    assert g.sh_degree == 1
    assert np.array_equal(g.sh[:, 2, 1], arr["f_rest_4"])  # G channel (3..5), coefficient 2
    assert np.array_equal(g.quats[:, 0], arr["rot_0"])
    # and it renders
    p = g.to_torch(torch.float64)
    from splat_scenes import look_at_camera
    img, _, _, _ = rasterize(*(p[k] for k in ("means", "quats", "log_scales", "opacity_logits", "sh")),
                             look_at_camera())
    assert torch.isfinite(img).all()


@pytest.mark.parametrize("kind,match", [
    ("missing", r"missing vertex attribute.*rot_3"),
    ("nan", r"NaN/inf.*scale_1"),
    ("sh_count", r"10 f_rest attributes"),
    ("gap", r"not numbered 0\.\.7"),
    ("corrupt", r"unreadable PLY"),
    ("absent", r"not found"),
    ("no_vertex", r"no 'vertex' element"),
])
def test_bad_ply_is_a_clear_error(tmp_path, kind, match):
    p = tmp_path / "bad.ply"
    if kind == "missing":
        _foreign_ply(p, drop=("rot_3",))
    elif kind == "nan":
        _foreign_ply(p, nan_in="scale_1")
    elif kind == "sh_count":
        _foreign_ply(p, K=4, extra=False)
        d = PlyData.read(str(p))["vertex"].data
        arr = np.empty(len(d), dtype=d.dtype.descr + [("f_rest_9", "<f4")])
        for nm in d.dtype.names:
            arr[nm] = d[nm]
        arr["f_rest_9"] = 0
        PlyData([PlyElement.describe(arr, "vertex")]).write(str(p))
    elif kind == "gap":
        _foreign_ply(p, drop=("f_rest_3",), K=4)
    elif kind == "corrupt":
        write_ply(p, _model())
        p.write_bytes(p.read_bytes()[:-1000])
    elif kind == "no_vertex":
        arr = np.zeros(3, dtype=[("a", "f4")])
        PlyData([PlyElement.describe(arr, "face_stuff")]).write(str(p))
    with pytest.raises(InputError, match=match) as e:
        read_ply(p)
    assert str(p) in str(e.value)


def test_writer_refuses_nan_and_leaves_no_file(tmp_path):
    g = _model()
    g.log_scales[4, 1] = np.inf
    with pytest.raises(InputError, match="log_scales"):
        write_ply(tmp_path / "x.ply", g)
    assert list(tmp_path.iterdir()) == []


def test_cameras_json_round_trip_and_render_camera(tmp_path):
    from gs2e.common.so3 import quat_to_rotmat
    from gs2e.io.scene import Camera, Frame, Scene
    rng = np.random.default_rng(2)
    frames = []
    for i in range(3):
        c2w = np.eye(4)
        c2w[:3, :3] = quat_to_rotmat(rng.normal(size=4))
        c2w[:3, 3] = rng.normal(size=3)
        frames.append(Frame(f"img_{i:03d}.png", Camera(100.0 + i, 101.0, 40.0, 30.0), c2w))
    frames.append(Frame("unposed.png", Camera(100.0, 101.0, 40.0, 30.0), None))
    scene = Scene(80, 60, frames)
    cams = cameras_from_scene(scene)
    assert [c.img_name for c in cams] == ["img_000", "img_001", "img_002"]
    write_cameras_json(tmp_path / "cameras.json", cams)
    raw = json.loads((tmp_path / "cameras.json").read_text())
    assert set(raw[0]) == {"id", "img_name", "width", "height", "position", "rotation", "fx", "fy"}
    back = read_cameras_json(tmp_path / "cameras.json")
    for a, b in zip(cams, back):
        assert np.allclose(a.c2w, b.c2w, atol=0, rtol=0) and a.fx == b.fx and a.img_name == b.img_name
    sc = back[1].splat_camera()
    assert np.allclose(sc.viewmat @ back[1].c2w, np.eye(4), atol=1e-12)
    assert (sc.cx, sc.cy, sc.width) == (40.0, 30.0, 80)


@pytest.mark.parametrize("edit,match", [
    (lambda d: d[0].pop("fy"), r"camera 0 lacks key\(s\) \['fy'\]"),
    (lambda d: d[1].__setitem__("position", [0, float("nan"), 0]), r"camera 1: NaN"),
    (lambda d: d[0].__setitem__("rotation", [[2, 0, 0], [0, 1, 0], [0, 0, 1]]), "not a proper rotation"),
    (lambda d: d[0].__setitem__("width", 0), "must be > 0"),
])
def test_bad_cameras_json(tmp_path, edit, match):
    c2w = np.eye(4)
    cams = [CameraEntry(i, f"v{i}", 64, 48, c2w, 50.0, 50.0) for i in range(2)]
    d = [c.to_json() for c in cams]
    edit(d)
    p = tmp_path / "cameras.json"
    p.write_text(json.dumps(d))
    with pytest.raises(InputError, match=match):
        read_cameras_json(p)
    p.write_text("[{")
    with pytest.raises(InputError, match="not valid JSON"):
        read_cameras_json(p)
