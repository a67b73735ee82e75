"""Base paths travelled back and forth (trajectory.min_duration_s): the time
map's legs and turns, the stages that must see a turn inside an interval
(blur motion, the motion clock), and recon3d's hold-out by position."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gs2e.bench import recon3d as R3
from gs2e.cli import main
from gs2e.events.settings import event_settings
from gs2e.testing import make_scene, ring
from gs2e.trajectory.io import load_trajectory, save_trajectory
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.stage import generate
from gs2e.trajectory.trajectory import Trajectory, back_and_forth


def _generate(**kw):
    cfg = TrajectorySettings.defaults(**kw, mini_frames=150)
    return generate(make_scene(ring(30, noise=0.01)), cfg, seed=3).trajectories


@pytest.fixture(scope="module")
def legs():
    """(one-way trajectories, the same lengthened to 2.5 s)."""
    return _generate(), _generate(min_duration_s=2.5)


def test_fast_presets_are_travelled_back_and_forth_up_to_the_minimum(legs):
    one, both = legs
    assert "legs" in both["base_strong"].meta and "legs" not in both["base_mild"].meta
    for name, tr in one.items():
        long = both[name]
        if name.startswith("mini") or tr.duration_us >= 2_500_000:
            # minis and paths already long enough are the same arrays
            for k, v in tr.to_arrays().items():
                assert np.array_equal(v, long.to_arrays()[k]), (name, k)
            continue
        D = tr.duration_us
        step = int(np.max(np.diff(tr.t_us)))
        assert 2_500_000 <= long.duration_us < 2_500_000 + step + 1
        assert long.meta["leg_duration_us"] == D
        assert long.meta["legs"] == pytest.approx(long.duration_us / D)
        n_turns = int(np.ceil(long.duration_us / D)) - 1
        assert np.array_equal(long.turns_us, D * np.arange(1, n_turns + 1))
        # the ends of the path at the turns, its mirror image on the way back
        P = long.pose_at(long.turns_us.astype(float))
        assert np.allclose(P[0::2], tr.c2w[-1], atol=1e-12) and np.allclose(P[1::2], tr.c2w[0], atol=1e-12)
        x = np.array([0.3, 0.5]) * D
        assert np.allclose(long.pose_at(D + x), tr.pose_at(D - x), atol=1e-9)
        if 3 * D <= long.duration_us:
            assert np.allclose(long.pose_at(2 * D + x), tr.pose_at(x), atol=1e-9)
        # the time map stays on the path (no overshoot at a turn) and is C1
        t = np.linspace(0.0, long.t_us[-1], 400_001)
        s = long.arc_length_at(t)
        assert s.min() >= -1e-12 and s.max() <= tr.s[-1] * (1 + 1e-12)
        v = np.diff(s) / np.diff(t)
        assert np.abs(np.diff(v)).max() < 0.05 * np.abs(v).max()
        assert long.length == pytest.approx(tr.length * long.meta["legs"], rel=0.02)
        assert long.length > tr.length


def test_the_trajectory_files_keep_the_legs(legs, tmp_path):
    tr = legs[1]["base_strong"]
    save_trajectory(tmp_path / "t.npz", tr)
    back = load_trajectory(tmp_path / "t.npz")
    assert np.array_equal(back.turns_us, tr.turns_us) and back.meta["legs"] == tr.meta["legs"]
    assert np.array_equal(back.monotone_spans(0, tr.duration_us),
                          np.r_[0.0, tr.turns_us.astype(float), tr.duration_us])
    one_way = legs[0]["base_strong"]
    assert one_way.turns_us.size == 0
    assert np.array_equal(one_way.monotone_spans(10, 20), [10.0, 20.0])


def test_a_path_starting_later_keeps_its_clock_and_too_many_legs_is_a_config_error(legs):
    from gs2e.common.errors import ConfigError

    tr = legs[0]["base_strong"]
    d = tr.to_arrays()
    d["t_us"] = d["t_us"] + 1_000_000
    late = back_and_forth(Trajectory.from_arrays(d), 3 * tr.duration_us)
    ref = back_and_forth(tr, 3 * tr.duration_us)
    assert np.array_equal(late.t_us, ref.t_us + 1_000_000) and np.array_equal(late.s, ref.s)
    assert np.array_equal(late.turns_us, ref.turns_us + 1_000_000)
    with pytest.raises(ConfigError, match="min_duration_s"):
        back_and_forth(tr, tr.duration_us * 10 ** 6)


def test_a_turn_next_to_a_zero_step_is_found(legs):
    tr = back_and_forth(legs[0]["base_strong"], 2 * legs[0]["base_strong"].duration_us)
    d = tr.to_arrays()
    j = int(np.searchsorted(d["t_us"], tr.turns_us[0]))
    d["s"][j + 1] = d["s"][j]  # the camera rests one sample at the turn
    rested = Trajectory.from_arrays(d)
    assert np.array_equal(rested.turns_us, [d["t_us"][j]])  # where it arrived


def test_a_long_enough_or_static_path_is_returned_as_it_is(legs):
    tr = legs[0]["base_mild"]
    assert back_and_forth(tr, tr.duration_us) is tr
    d = tr.to_arrays()
    d["t_us"], d["s"], d["ds_dt"], d["c2w"] = d["t_us"][:1], d["s"][:1], d["ds_dt"][:1], d["c2w"][:1]
    single = Trajectory.from_arrays(d)
    assert back_and_forth(single, 10 ** 6) is single


def test_min_duration_is_validated():
    from gs2e.common.errors import ConfigError
    from gs2e.config import load_config

    with pytest.raises(ConfigError, match="min_duration_s"):
        load_config({"trajectory": {"min_duration_s": 0}})
    assert load_config({"trajectory": {"min_duration_s": 1.5}})["trajectory"]["min_duration_s"] == 1.5


# ------------------------------------------------------------------ stages that see the turns
@pytest.fixture(scope="module")
def plane_legs(tmp_path_factory):
    """The tests' plane model and its pan (30 ms one way) travelled back and
    forth over 0.2 s: a turn every 30 ms."""
    from gs2e.testing import plane_model, straight_trajectory

    tmp = tmp_path_factory.mktemp("legs")
    model = plane_model(tmp)
    d = load_trajectory(straight_trajectory(tmp, dx=0.6)).to_arrays()
    f = d["t_us"][-1] / 30_000
    d["t_us"] = np.round(d["t_us"] / f).astype(np.int64)
    d["ds_dt"] = d["ds_dt"] * f
    tr = back_and_forth(Trajectory.from_arrays(d), 200_000)
    assert np.array_equal(tr.turns_us, 30_000 * np.arange(1, 7))
    path = tmp / "legs.npz"
    save_trajectory(path, tr)
    return tmp, model, path


def test_blur_counts_the_motion_out_and_back_within_an_exposure(plane_legs):
    """Frames at 1/30 ms sit on the turns: the exposure's ends are the same
    pose, yet the camera moved 10 ms out and back."""
    import pandas as pd

    tmp, model, traj = plane_legs
    out = tmp / "frames"
    cfg = {"fps": 1e6 / 30_000, "exposure_us": 20_000.0, "write_depth": False, "min_coverage": 0.0,
           "blur_tolerance_db": None}
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(out),
                 "--threads", "1", "--config-json", json.dumps(cfg)]) == 0
    f = pd.read_parquet(out / "frames.parquet")
    turn = f[f["t_us"].isin([30_000, 60_000, 90_000])]
    assert len(turn) == 3
    tr = load_trajectory(traj)
    c2w = tr.pose_at(np.array([20_000.0, 30_000.0, 40_000.0]))
    assert np.allclose(c2w[0], c2w[2], atol=1e-9)  # the ends of the exposure coincide
    # 10 ms each way over the 0.6-unit pan done in 30 ms, seen at depth 2 with f = 60 px
    one_way_px = 0.6 / 3 * 60.0 / 2.0
    assert (turn["motion_px_p50"] > 1.5 * one_way_px).all(), turn["motion_px_p50"].tolist()
    assert (turn["n_subframes"] > 1).all()
    from gs2e.io.images import read_image

    k = int(turn.index[0])
    blur, sharp = (read_image(out / d / f"{k:06d}.png").astype(float) for d in ("blur", "rgb"))
    assert np.abs(blur - sharp).mean() > 2.0  # on 0..255: the blur is not the sharp frame


@pytest.mark.parametrize("mode", ["motion", "adaptive"])
def test_the_motion_and_adaptive_clocks_sample_every_turn(plane_legs, mode):
    from gs2e.events.rendered import RenderedSource

    tmp, model, traj = plane_legs
    cfg = event_settings({"model": "ideal", "sampling": {"mode": mode, "max_motion_px": 2.0}})
    src = RenderedSource(model, traj, cfg)
    src.start()
    times = np.array([t for b, _ in src.batches() for t in b])
    assert np.all(np.diff(times) > 0) and times[0] > 0 and times[-1] == 200_000
    assert set(range(30_000, 200_000, 30_000)) <= set(times.tolist())
    assert src.stats.accepted == len(times) + 1  # t0 and every batch time, none twice


# ------------------------------------------------------------------ recon3d's hold-out
def test_split_by_position_holds_out_pieces_of_the_path_on_every_leg():
    rng = np.random.default_rng(0)
    usable = list(range(100))
    pos = rng.uniform(0, 1, 100)
    train, test = R3.split_by_position(usable, pos, 8, frames_per_leg=30.0)
    assert sorted(train + test) == usable and not set(train) & set(test)
    n = 8 * 4  # round(30 / 8) = 4 pieces of 8
    piece = np.floor(pos * n).astype(int)
    assert all(piece[i] % 8 == 4 for i in test) and all(piece[i] % 8 != 4 for i in train)
    assert 5 <= len(test) <= 25
    # a leg shorter than a frame: 8 pieces, one held out
    train, test = R3.split_by_position(usable, pos, 8, frames_per_leg=0.9)
    assert all(0.5 <= pos[i] < 0.625 for i in test)
    assert not any(0.5 <= pos[i] < 0.625 for i in train)
    assert R3.split_by_position([3], np.array([0.5]), 8, 1.0) == ([3], [])
    # the path's ends belong to the first and last pieces, never held out
    assert not R3.in_held_out_piece(np.array([0.0, 1.0]), 8, 30.0).any()


def test_recon3d_holds_out_by_position_on_a_back_and_forth_path(plane_legs):
    from gs2e.bench.dataset import load_dataset

    tmp, model, traj = plane_legs
    out = tmp / "frames90"
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(out),
                 "--threads", "1", "--config-json", json.dumps(
                     {"fps": 90.0, "exposure_us": 8_000.0, "write_depth": False, "min_coverage": 0.0})]) == 0
    cfg = {"model": "ideal", "theta_on": 0.1, "theta_off": 0.1, "preview": False,
           "sampling": {"mode": "fixed", "fixed_fps": 2400.0}}
    assert main(["events", "--model", str(model), "--trajectory", str(traj), "-o", str(tmp / "events"),
                 "--seed", "0", "--threads", "1", "--config-json", json.dumps(cfg)]) == 0
    assert main(["windows", "--frames", str(out), "--events", str(tmp / "events"),
                 "--out", str(tmp / "windows.parquet")]) == 0
    ds = load_dataset("recon3d", out, tmp / "events", tmp / "windows.parquet", traj)
    from gs2e.config import load_section

    data = R3.recon3d_data(ds, R3.recon3d_settings(load_section("bench"), test_every=4))
    tr = load_trajectory(traj)
    pos = tr.arc_length_at(data.t_us) / tr.s.max()
    n = 4 * max(1, round(0.03 * 90 / 4))  # 2.7 frames per 30 ms leg: 4 pieces
    piece = np.minimum(n - 1, np.floor(pos * n)).astype(int)
    assert len(data.test_idx) >= 2 and all(piece[i] == 2 for i in data.test_idx)
    assert all(piece[i] != 2 for i in data.train_idx)
    # the test frames lie on legs of both directions, which an every-4th rule would not respect
    legs = (data.t_us[data.test_idx] // 30_000) % 2
    assert set(legs.tolist()) == {0, 1}
    assert data.test_idx != R3.split_frames(sorted(data.train_idx + data.test_idx), 4)[1]
    # event_blur trains on no blurred frame whose exposure sweeps through a held-out piece
    blurred = sorted(data.blurred)
    assert set(blurred) < set(data.train_idx)
    for i in data.train_idx:
        ts = data.t_us[i] + np.linspace(-4_000.0, 4_000.0, 201)
        p = np.minimum(n - 1, np.floor(tr.arc_length_at(ts) / tr.s.max() * n)).astype(int)
        assert (i in blurred) == (not (p == 2).any()), i


def test_make_table1_data_plan_is_valid(tmp_path):
    """config/table1.tsv (make table1's data): three real scenes, the three base
    speeds each, one recon3d job per speed."""
    from gs2e.testing import run_snakemake
    from tests.conftest import REPO, planned_jobs, shared_data

    shared_data("mouse_colmap")
    proc = run_snakemake("-n", "--cores", "2", "--directory", str(REPO), "--config",
                         f"scenes={REPO / 'config' / 'table1.tsv'}", f"results_dir={tmp_path / 'out'}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = planned_jobs(proc.stdout)
    assert jobs["train"] == 3 and jobs["events"] == 9 and jobs["bench"] == 9
