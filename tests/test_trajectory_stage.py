"""Whole stage: mini-trajectories, presets, files, CLI, determinism, errors."""

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gs2e.testing import TEMPLE, fine_steps, make_scene, ring, temple_c2w
from gs2e.common.errors import ConfigError
from gs2e.common.so3 import geodesic_angle
from gs2e.config import load_section
from gs2e.io.scene import write_scene_json
from gs2e.trajectory.io import load_trajectory, read_index, write_outputs
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.stage import generate

REPO = Path(__file__).resolve().parents[1]


def cfg(**kw) -> TrajectorySettings:
    return TrajectorySettings.defaults(**kw)


def _hashes(folder: Path) -> dict:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def test_generate_presets_and_minis():
    scene = make_scene(ring(30, noise=0.01))
    c = cfg(mini_frames=150)
    res = generate(scene, c, seed=3)
    names = sorted(res.trajectories)
    assert names == ["base_medium", "base_mild", "base_strong",
                     "mini00_medium", "mini01_medium", "mini02_medium"]
    durs = {n: res.trajectories[n].duration_us for n in ("base_mild", "base_medium", "base_strong")}
    assert durs["base_mild"] > durs["base_medium"] > durs["base_strong"] > 0
    for name, tr in res.trajectories.items():
        assert tr.t_us.dtype == np.int64 and np.all(np.diff(tr.t_us) > 0) and tr.t_us[0] == 0
        # the preset bound holds (peak frame-to-frame speeds) and one of them is binding
        pv = tr.meta["preset_values"]
        dt = np.diff(tr.t_us) * 1e-6
        ang = np.degrees(geodesic_angle(tr.c2w[:-1, :3, :3], tr.c2w[1:, :3, :3])) / dt
        lin = np.linalg.norm(np.diff(tr.c2w[:, :3, 3], axis=0), axis=1) / tr.meta["translation_scale"] / dt
        r_ang, r_lin = ang.max() / pv["max_angular_speed_deg_s"], lin.max() / pv["max_linear_speed_scale_s"]
        assert max(r_ang, r_lin) == pytest.approx(1.0, abs=2e-3), name
    # base presets share the path; only the time axis differs
    np.testing.assert_array_equal(res.trajectories["base_mild"].c2w, res.trajectories["base_strong"].c2w)
    for g in range(3):
        tr = res.trajectories[f"mini{g:02d}_medium"]
        m = tr.meta
        assert len(tr.c2w) == 150
        kf = np.asarray(m["keyframes"])
        assert len(kf) == 5 and np.all(np.diff(kf) > 0)
        # endpoints are the first and last keyframes
        np.testing.assert_allclose(tr.c2w[[0, -1]], res.base.c2w[kf[[0, -1]]], atol=1e-9)
        # uniform in true arc length (independent sub-step measure) to 1e-3 per step
        d = fine_steps(tr, m["alpha"], m["beta"] / m["translation_scale"])
        assert np.abs(d / d.mean() - 1).max() < 1e-3
        assert m["method"] in ("bspline", "bezier", "bspline (bezier fallback)")
        assert 2 <= m["degree"] <= 5
    all_kf = np.concatenate([res.trajectories[f"mini{g:02d}_medium"].meta["keyframes"] for g in range(3)])
    assert len(set(all_kf.tolist())) == 15  # without replacement


def test_minis_use_first_keyframe_intrinsics_and_both_families():
    c2w = ring(30, noise=0.01)
    scene = make_scene(c2w)
    for i, f in enumerate(scene.frames):  # distinct intrinsics per frame
        f.camera = type(f.camera)(40.0 + i, 40.0 + i, 32, 24)
    res = generate(scene, cfg(mini_groups=12, smooth_half_width=0), seed=0)
    methods = set()
    for name, tr in res.trajectories.items():
        if name.startswith("mini"):
            methods.add(tr.meta["method"].split()[0])
            src = tr.meta["intrinsics_from_frame"]
            assert tr.K[0, 0] == 40.0 + src
            # nearest input frame to the first keyframe (by centre distance, on a ring)
            C0 = tr.c2w[0, :3, 3]
            near = np.argsort(np.linalg.norm(c2w[:, :3, 3] - C0, axis=1))[:2]
            assert src in near
    assert methods == {"bspline", "bezier"}


@pytest.mark.parametrize("n", [1, 2, 3])
def test_stage_on_tiny_scenes(n):
    res = generate(make_scene(ring(n, arc=0.5)), cfg(smooth_half_width=2), seed=1)
    assert len(res.trajectories) == 6
    for name, tr in res.trajectories.items():
        assert np.all(np.isfinite(tr.c2w)) and np.all(np.diff(tr.t_us) > 0), name
        if n == 1:  # a static camera: one base frame per pose
            assert tr.length == 0.0
            assert tr.duration_us == round((len(tr.t_us) - 1) / 2400 * 1e6)


def test_determinism_same_seed_same_bytes(tmp_path):
    scene = make_scene(ring(16, noise=0.02))
    c = cfg(plot=False)
    outs = []
    for k, seed in enumerate([5, 5, 6]):
        res = generate(scene, c, seed)
        outs.append(_hashes(write_outputs(tmp_path / f"o{k}", res, c, "scene", plot=False)))
    assert outs[0] == outs[1]
    assert outs[0]["base_medium.npz"] == outs[2]["base_medium.npz"]  # base does not use the seed
    assert outs[0]["mini00_medium.npz"] != outs[2]["mini00_medium.npz"]


def test_files_roundtrip(tmp_path):
    scene = make_scene(ring(12, noise=0.02))
    res = generate(scene, cfg(), 0)
    write_outputs(tmp_path / "out", res, cfg(), "scene", plot=True)
    idx = read_index(tmp_path / "out")
    assert {e["name"] for e in idx["trajectories"]} == set(res.trajectories)
    assert (tmp_path / "out" / "trajectories.png").stat().st_size > 10_000
    for e in idx["trajectories"]:
        tr = load_trajectory(tmp_path / "out" / e["file"])
        orig = res.trajectories[e["name"]]
        np.testing.assert_array_equal(tr.c2w, orig.c2w)
        assert tr.t_us.dtype == np.int64 and tr.width == 64 and tr.height == 48
        q = np.linspace(0, tr.t_us[-1], 1001)
        np.testing.assert_array_equal(tr.pose_at(q), orig.pose_at(q))
        np.testing.assert_array_equal(tr.pose_at(tr.t_us), tr.c2w)
        assert e["duration_us"] == tr.duration_us


def test_config_errors():
    scene = make_scene(ring(8))
    with pytest.raises(ConfigError, match="trajectory.speed_presets.0': 'fast' is not one of"):
        generate(scene, cfg(speed_presets=["fast"]), 0)
    with pytest.raises(ConfigError, match="alpha"):
        generate(scene, cfg(alpha=0.0, beta=0.0), 0)
    with pytest.raises(ConfigError, match="trajectory.velocity"):
        generate(scene, cfg(velocity="0.5 - t"), 0)
    with pytest.raises(ConfigError, match="trajectory.velocity"):
        generate(scene, cfg(velocity="__import__('os')"), 0)
    with pytest.raises(ConfigError, match="speed_list"):
        load_section("trajectory", text=json.dumps({"speed_list": [1, -2]}))
    with pytest.raises(ConfigError, match="gamma"):
        load_section("trajectory", text=json.dumps({"gamma": 0.5}))


def _cli(*args):
    import os
    env = {**os.environ, "PYTHONPATH": str(REPO), "GS2E_PROGRESS": "0"}
    return subprocess.run([sys.executable, "-m", "gs2e", *args], cwd=REPO, capture_output=True,
                          text=True, env=env, timeout=300)


def test_cli_end_to_end(tmp_path):
    if TEMPLE.exists():
        c2w = temple_c2w(30)
        scene = make_scene(c2w, 640, 480)
    else:
        scene = make_scene(ring(30, noise=0.01))
    (tmp_path / "scene").mkdir()
    write_scene_json(scene, tmp_path / "scene")
    r = _cli("trajectory", "--scene", str(tmp_path / "scene"), "--out", str(tmp_path / "out"),
             "--config-json", json.dumps({"gamma": 5, "mini_groups": 3}), "--seed", "7")
    assert r.returncode == 0, r.stderr
    idx = read_index(tmp_path / "out")
    assert len(idx["trajectories"]) == 6 and idx["config"]["gamma"] == 5
    assert (tmp_path / "out" / "trajectories.png").exists()
    assert "base trajectory done in" in r.stderr
    # same seed again -> same bytes
    r = _cli("trajectory", "--scene", str(tmp_path / "scene"), "--out", str(tmp_path / "out2"),
             "--config-json", json.dumps({"gamma": 5, "mini_groups": 3}), "--seed", "7")
    assert r.returncode == 0, r.stderr
    assert _hashes(tmp_path / "out") == _hashes(tmp_path / "out2")


def test_cli_errors_leave_no_output(tmp_path):
    (tmp_path / "scene").mkdir()
    write_scene_json(make_scene(ring(6)), tmp_path / "scene")
    sj = tmp_path / "scene" / "scene.json"
    data = json.loads(sj.read_text())
    data["frames"][2]["c2w"][0][3] = float("nan")
    sj.write_text(json.dumps(data))  # Python's json writes the NaN literal
    r = _cli("trajectory", "--scene", str(tmp_path / "scene"), "--out", str(tmp_path / "out"))
    assert r.returncode == 2
    assert "NaN" in r.stderr and "002.png" in r.stderr
    assert not (tmp_path / "out").exists()
    write_scene_json(make_scene(ring(6)), tmp_path / "scene")
    r = _cli("trajectory", "--scene", str(tmp_path / "scene"), "--out", str(tmp_path / "out"),
             "--config-json", json.dumps({"velocity": "t - 0.5"}))
    assert r.returncode == 2 and "trajectory.velocity" in r.stderr
    assert not (tmp_path / "out").exists()
    assert not any(p.name.startswith(".out") for p in tmp_path.iterdir())


def test_config_section_complete_and_documented():
    from gs2e.config import load_schema

    sec = load_schema()["properties"]["trajectory"]

    def walk(node, path):
        for k, sub in node.get("properties", {}).items():
            assert "description" in sub and "default" in sub, f"{path}{k}"
            if sub.get("type") == "object":
                assert sub.get("additionalProperties") is False, f"{path}{k}"
                walk(sub, f"{path}{k}.")

    walk(sec, "trajectory.")
    assert sec["properties"]["velocity"]["default"] == "0.25*sin(t)+1.1"


def test_presets_set_the_typical_image_speed_when_the_scene_has_points():
    """With sparse points, each preset's time scale makes the median over the path
    of the median point's image speed its image_speed_width_s (image widths per
    second), for the base path and the mini-trajectories alike."""
    from gs2e.trajectory.trajectory import image_steps_width

    scene = make_scene(ring(30, noise=0.01))
    scene.points_xyz = np.random.default_rng(0).normal(scale=0.3, size=(500, 3))
    c = cfg(mini_frames=60)
    res = generate(scene, c, seed=3)
    for name, tr in res.trajectories.items():
        want = tr.meta["preset_values"]["image_speed_width_s"]
        steps = image_steps_width(tr.c2w, tr.K, scene.width, scene.height, scene.points_xyz)
        speed = steps / (np.diff(tr.t_us) * 1e-6)
        assert np.median(speed) == pytest.approx(want, rel=2e-3), name
    d = {p: res.trajectories[f"base_{p}"].duration_us for p in ("mild", "medium", "strong")}
    v = {p: c.presets[p]["image_speed_width_s"] for p in d}
    assert d["mild"] / d["strong"] == pytest.approx(v["strong"] / v["mild"], rel=1e-3)
    assert res.trajectories["base_mild"].meta["image_step_width_median"] > 0
