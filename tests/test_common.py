"""Shared helpers: atomic outputs, rotations, code versions."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.common.atomic import atomic_dir, atomic_file, write_json_atomic
from gs2e.common.so3 import geodesic_angle, quat_to_rotmat, rotmat_to_quat, umeyama
from gs2e import codeversion


def test_atomic_dir_leaves_nothing_on_failure(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with atomic_dir(out) as d:
            (d / "partial.txt").write_text("x")
            raise RuntimeError("boom")
    assert not out.exists()
    assert list(tmp_path.iterdir()) == []


def test_atomic_dir_replaces_existing_on_success(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old")
    with atomic_dir(out) as d:
        (d / "new.txt").write_text("new")
    assert sorted(p.name for p in out.iterdir()) == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_atomic_file_and_json(tmp_path):
    with pytest.raises(ValueError):
        with atomic_file(tmp_path / "f.bin") as fh:
            fh.write(b"abc")
            raise ValueError
    assert list(tmp_path.iterdir()) == []
    write_json_atomic(tmp_path / "a.json", {"x": np.arange(3), "y": np.float32(1.5)})
    assert (tmp_path / "a.json").read_text().count("\n") > 1
    with pytest.raises(ValueError):  # NaN is not valid JSON: refuse rather than write it
        write_json_atomic(tmp_path / "b.json", {"x": float("nan")})
    assert not (tmp_path / "b.json").exists()


def _random_rotations(n, rng):
    q = rng.normal(size=(n, 4))
    return quat_to_rotmat(q / np.linalg.norm(q, axis=1, keepdims=True))


def test_quaternion_round_trip_including_180_degrees():
    rng = np.random.default_rng(0)
    R = _random_rotations(200, rng)
    # 180-degree rotations about random axes: the hard case for matrix->quaternion.
    axes = rng.normal(size=(50, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R180 = 2 * axes[:, :, None] * axes[:, None, :] - np.eye(3)
    for Rs in (R, R180, np.eye(3)[None]):
        q = rotmat_to_quat(Rs)
        assert np.allclose(quat_to_rotmat(q), Rs, atol=1e-12)
        assert np.all(q[:, 0] >= 0)


def test_geodesic_angle_is_accurate_near_zero_and_pi():
    for ang in (1e-9, 1e-5, 0.3, np.pi - 1e-6, np.pi - 1e-9, np.pi):
        axis = np.array([1.0, 2.0, -0.5])
        axis /= np.linalg.norm(axis)
        q = np.concatenate([[np.cos(ang / 2)], np.sin(ang / 2) * axis])
        R = quat_to_rotmat(q)
        got = geodesic_angle(np.eye(3), R)
        assert abs(got - ang) <= 1e-12 + 1e-9 * ang, (ang, got)


def test_umeyama_recovers_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(30, 3))
    R = _random_rotations(1, rng)[0]
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 0.5])
    s, R_est, t = umeyama(src, dst)
    assert np.isclose(s, 2.5) and np.allclose(R_est, R) and np.allclose(t, [1, -2, 0.5])


def test_code_version_tracks_stage_sources(tmp_path, monkeypatch):
    import shutil

    pkg = tmp_path / "gs2e"
    shutil.copytree(codeversion.PKG, pkg, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(codeversion, "PKG", pkg)
    codeversion.code_version.cache_clear()
    v_sfm, v_demo = codeversion.code_version("sfm"), codeversion.code_version("demo")
    with open(pkg / "sfm" / "align.py", "a") as fh:
        fh.write("\n# edit\n")
    codeversion.code_version.cache_clear()
    assert codeversion.code_version("sfm") != v_sfm      # sfm depends on gs2e/sfm
    assert codeversion.code_version("demo") == v_demo    # demo does not
    codeversion.code_version.cache_clear()
