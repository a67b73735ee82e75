"""Shared helpers: atomic outputs, rotations, code versions."""

from __future__ import annotations

import json

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
    # NaN/inf are not valid JSON: they mean "could not be computed" and become null
    write_json_atomic(tmp_path / "b.json", {"x": float("nan"), "y": [np.float32("inf"), 1.0],
                                            "z": {"w": -np.inf}})
    assert json.loads((tmp_path / "b.json").read_text()) == {"x": None, "y": [None, 1.0],
                                                             "z": {"w": None}}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "b.json"]


def _killed_writer(tmp_path, code: str) -> None:
    """Run ``code`` (with gs2e.common.atomic imported as A) in a child that is
    SIGKILLed inside the writer; returns when it is gone."""
    import signal
    import subprocess
    import sys

    child = subprocess.Popen([sys.executable, "-c", "import os, signal\n"
                              "from gs2e.common import atomic as A\n" + code], cwd=tmp_path)
    assert child.wait(60) == -signal.SIGKILL


def test_temporaries_of_killed_writers_are_swept_by_the_next_write(tmp_path):
    from gs2e.common.atomic import atomic_dir, atomic_path, parse_temporary, sweep_output

    _killed_writer(tmp_path, "with A.atomic_dir('out') as d:\n"
                             "    (d / 'x').write_text('partial')\n"
                             "    os.kill(os.getpid(), signal.SIGKILL)")
    _killed_writer(tmp_path, "with A.atomic_path('t.h5') as p:\n"
                             "    p.write_text('partial')\n"
                             "    os.kill(os.getpid(), signal.SIGKILL)")
    left = sorted(tmp_path.iterdir())
    assert [p.name.split("-")[0] for p in left] == [".out.tmp", ".t.h5.tmp"]
    t = parse_temporary(left[1])
    assert t.final_name == "t.h5" and t.alive is False and left[1].suffix == ".h5"
    # a live writer's temporary (this process) is never swept
    with atomic_dir(tmp_path / "out") as d:
        assert sweep_output(tmp_path / "out") == [] and d.exists()
        assert len([p for p in tmp_path.iterdir() if p.name.startswith(".out.tmp")]) == 1
        (d / "y").write_text("complete")
    with atomic_path(tmp_path / "t.h5") as p:
        p.write_text("complete")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "t.h5"]
    assert (tmp_path / "out" / "y").read_text() == "complete"


def test_owner_of_a_temporary(tmp_path):
    import os

    from gs2e.common.atomic import owner_tag, parse_temporary

    me = parse_temporary(tmp_path / f".a.b.tmp-{owner_tag()}-abcd_123.npz")
    assert me.final_name == "a.b" and me.alive is True
    pid, rest = owner_tag().split("-", 1)
    start, host = rest.split("@")
    # same pid, other start time: the pid was reused, the owner is gone
    reused = parse_temporary(tmp_path / f".x.tmp-{pid}-{int(start) + 1}@{host}-abcdefgh")
    assert reused.alive is False
    other = parse_temporary(tmp_path / f".x.tmp-{pid}-{start}@node-07.cluster-abcdefgh")
    assert other.alive is None and other.owner.endswith("@node-07.cluster")
    assert parse_temporary(tmp_path / ".x.tmp-abcdefgh").owner is None  # untagged (older gs2e)
    for name in ("x.tmp-abcdefgh", ".x.tmp", ".x.txt", "frames"):
        assert parse_temporary(tmp_path / name) is None
    assert os.getpid() == int(pid)


def test_clean_removes_only_stale_temporaries(tmp_path):
    from gs2e.cli import main
    from gs2e.common.atomic import owner_tag

    res = tmp_path / "results"
    (res / "s" / "frames").mkdir(parents=True)
    (res / "s" / "frames" / "t1").mkdir()  # an output: kept
    pid, rest = owner_tag().split("-", 1)
    start, host = rest.split("@")
    dead = res / "s" / "frames" / f".t1.tmp-999999999-1@{host}-abcdefgh"
    (dead / "rgb").mkdir(parents=True)
    (dead / "rgb" / "0.png").write_bytes(b"x" * 1000)
    live = res / "s" / f".splat.tmp-{owner_tag()}-abcdefgh"
    live.mkdir()
    foreign = res / "s" / f".sfm.tmp-12-34@elsewhere-abcdefgh"
    foreign.mkdir()
    assert main(["clean", str(res), "--dry-run"]) == 0 and dead.exists()
    assert main(["clean", str(res)]) == 0
    assert not dead.exists() and live.exists() and foreign.exists()
    assert (res / "s" / "frames" / "t1").is_dir()
    assert main(["clean", str(res), "--all-hosts"]) == 0
    assert not foreign.exists() and live.exists()


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


def test_write_metrics_types_missing_values_and_no_pandas(tmp_path):
    import subprocess
    import sys

    import pandas as pd
    import pyarrow.parquet as pq

    from gs2e.metrics.table import write_metrics

    p = tmp_path / "m.parquet"
    write_metrics(p, [{"psnr": np.float32("nan"), "n": np.int64(3), "ok": np.bool_(True),
                       "hist": np.array([1.5, np.inf])},
                      {"psnr": 31.25, "name": "a b", "n": None, "extra": 2}], scene_id="s")
    t = pq.read_table(p)
    assert t.column_names == ["scene_id", "psnr", "n", "ok", "hist", "name", "extra"]
    assert str(t.schema.field("n").type) == "int64" and str(t.schema.field("ok").type) == "bool"
    assert str(t.schema.field("psnr").type) == "double"  # 31.25 after a NaN: not an int column
    d = t.to_pylist()
    assert d[0]["psnr"] is None and d[1]["psnr"] == 31.25  # not computable -> null
    assert d[0]["hist"] == [1.5, None] and d[1]["hist"] is None
    assert d[1]["n"] is None and d[0]["extra"] is None and d[1]["name"] == "a b"
    assert pd.read_parquet(p)["scene_id"].tolist() == ["s", "s"]
    x = 0.1 + 0.2  # floats survive the JSON round trip bit for bit
    write_metrics(p, {"x": x, "tiny": 5e-324})
    assert pq.read_table(p).to_pylist() == [{"x": x, "tiny": 5e-324}]
    # pyarrow imports pandas when it builds arrays from Python objects (~0.2 s)
    code = ("import sys; from gs2e.metrics.table import write_metrics; "
            f"write_metrics({str(p)!r}, {{'a': 1.0}}); print('pandas' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "False"


def test_render_scale_beyond_the_size_limit_is_a_config_error():
    """render.scale x the camera's size is checked before any frame buffer:
    a one-line error naming the key; sizes at the limit pass."""
    from gs2e.common.camera import MAX_SIDE_PX, render_camera
    from gs2e.common.errors import ConfigError

    K = np.array([[3000.0, 0, 1600], [0, 3000.0, 1200], [0, 0, 1]])
    with pytest.raises(ConfigError, match=r"render.scale=8 on the 3200x2400 camera.*25600x19200"):
        render_camera(K, 3200, 2400, 8.0)
    _, W, H = render_camera(K, 3200, 2400, MAX_SIDE_PX / 3200 * 0.5)
    assert (W, H) == (MAX_SIDE_PX // 2, 3 * MAX_SIDE_PX // 8)
    # with a sensor, scale does not apply and the sensor's own check governs
    assert render_camera(K, 3200, 2400, 8.0, ((346, 260), "cover"))[1:] == (346, 260)
