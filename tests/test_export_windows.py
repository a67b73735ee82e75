"""Aligned event windows: hard cases of the pure function, and the table the
default workflow writes on the tiny pipeline (events on part of the trajectory)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import InputError
from gs2e.export.windows import compute_windows, covered_frame_range, exposure_bounds_us, read_windows


def _events(ts):
    return np.asarray(ts, np.int64)


def test_events_on_a_frame_time_belong_to_the_window_that_starts_there():
    t = np.array([1000, 2000, 3000])
    ev = _events([1000, 1999, 2000, 2000, 2999, 3000])
    w = compute_windows(t, np.zeros(3), ev, (1000, 3000))
    assert not w.loc[0, "inter_covered"] and pd.isna(w.loc[0, "inter_i0"])  # no previous frame
    assert (w.loc[1, "inter_i0"], w.loc[1, "inter_i1"]) == (0, 2)    # [1000, 2000)
    assert (w.loc[2, "inter_i0"], w.loc[2, "inter_i1"]) == (2, 5)    # [2000, 3000)
    # the event at exactly the last frame time is in no inter-frame window
    assert w["inter_i1"].max() == 5


def test_windows_outside_the_simulated_span_are_not_covered_never_empty():
    t = np.array([0, 100, 200, 300])
    ev = _events([10, 20, 150])
    w = compute_windows(t, np.zeros(4), ev, (0, 160))  # events simulated on [0, 160] only
    assert w["inter_covered"].tolist() == [False, True, False, False]
    assert w.loc[1, "inter_i1"] - w.loc[1, "inter_i0"] == 2
    assert w.loc[2:, "inter_i0"].isna().all() and w.loc[2:, "inter_i1"].isna().all()
    # a covered window without events is empty, not missing
    w2 = compute_windows(t, np.zeros(4), _events([]), (0, 300))
    assert w2["inter_covered"].tolist() == [False, True, True, True]
    assert (w2.loc[1:, "inter_i1"] - w2.loc[1:, "inter_i0"]).eq(0).all()


def test_exposure_is_clipped_to_the_trajectory_and_uses_ceiled_bounds():
    t = np.array([0, 1000, 2000])
    a, b = exposure_bounds_us(t, np.full(3, 501.0), 0, 2000)  # half = 250.5 us
    assert a.tolist() == [0, 750, 1750]       # ceil(1000 - 250.5) = 750
    assert b.tolist() == [251, 1251, 2000]    # ceil(250.5) = 251; clipped at the last frame
    ev = _events([749, 750, 1250, 1251, 1999, 2000])
    w = compute_windows(t, np.full(3, 501.0), ev, (0, 2000))
    assert (w.loc[1, "exp_i0"], w.loc[1, "exp_i1"]) == (1, 3)  # 750 <= t < 1250.5
    assert (w.loc[2, "exp_i0"], w.loc[2, "exp_i1"]) == (4, 5)  # [1749.5, 2000)
    assert w["exp_covered"].all()


def test_no_blurred_frames_and_single_frame_are_valid():
    w = compute_windows(np.array([5, 10]), np.zeros(2), _events([6]), (5, 10))
    assert w["exp_t0_us"].isna().all() and not w["exp_covered"].any()
    one = compute_windows(np.array([5]), np.array([4.0]), _events([5, 6]), (5, 5))
    assert len(one) == 1 and not one["inter_covered"].any()
    # the exposure is clipped to the one-instant trajectory: an empty, covered window
    assert one.loc[0, "exp_covered"] and (one.loc[0, "exp_i0"], one.loc[0, "exp_i1"]) == (0, 0)
    empty = compute_windows(np.zeros(0, np.int64), np.zeros(0), _events([]), (0, 0))
    assert len(empty) == 0


def test_bad_inputs_fail_clearly():
    with pytest.raises(InputError, match="not strictly increasing"):
        compute_windows(np.array([0, 0]), np.zeros(2), _events([]), (0, 1))
    with pytest.raises(InputError, match="not sorted"):
        compute_windows(np.array([0, 10]), np.zeros(2), _events([5, 1]), (0, 10))
    with pytest.raises(InputError, match="integer microseconds"):
        compute_windows(np.array([0, 10]), np.zeros(2), np.array([0.5]), (0, 10))


def test_covered_frame_range():
    w = pd.DataFrame({"inter_covered": [False, True, True, False, True]})
    assert covered_frame_range(w, "x") == (0, 2)
    with pytest.raises(InputError, match="fewer than two consecutive frames"):
        covered_frame_range(pd.DataFrame({"inter_covered": [False, False]}), "x.h5")


def test_workflow_writes_windows_that_slice_the_events(tiny_pipeline):
    """The default workflow's windows table on the tiny run (30 ms of events,
    frames every 100 ms): indices give exactly the events of each covered
    window; windows past the simulated span are flagged, not empty."""
    from gs2e.events.io import read_h5

    wd, _ = tiny_pipeline
    scene = wd / "results" / "tiny"
    w, meta = read_windows(scene / "windows" / "mini00_medium.parquet")
    ev, attrs = read_h5(scene / "events" / "mini00_medium" / "events.h5")
    assert meta["n_events"] == len(ev) > 0 and meta["t_offset_us"] == attrs["t_offset"]
    assert meta["sim_end_us"] - meta["sim_start_us"] == 30_000
    frames = pd.read_parquet(scene / "frames" / "mini00_medium" / "frames.parquet")
    assert w["t_us"].tolist() == frames["t_us"].tolist()
    beyond = w["inter_t1_us"] > meta["sim_end_us"] + 1
    assert beyond.any() and not w.loc[beyond, "inter_covered"].any()
    assert w.loc[beyond, "inter_i0"].isna().all()
    # frame 0's exposure (clipped to [t0, t0 + 10 ms)) lies inside the 30 ms of events
    assert w.loc[0, "exp_covered"]
    for kind in ("inter", "exp"):
        for _, r in w[w[f"{kind}_covered"]].iterrows():
            a, b = int(r[f"{kind}_i0"]), int(r[f"{kind}_i1"])
            t0, t1 = int(r[f"{kind}_t0_us"]), int(r[f"{kind}_t1_us"])
            assert (ev.t[a:b] >= t0).all() and (ev.t[a:b] < t1).all()
            assert (a == 0 or ev.t[a - 1] < t0) and (b == len(ev) or ev.t[b] >= t1)
            sub, _ = read_h5(scene / "events" / "mini00_medium" / "events.h5", (t0, t1))
            assert len(sub) == b - a


def test_export_rule_is_off_by_default_and_planned_alone_when_configured(tiny_pipeline):
    """export.formats: [] plans nothing; asking for a format plans one export job
    per trajectory and nothing else (exports change no dataset product or table)."""
    from tests.conftest import planned_jobs, run_snakemake

    wd, _ = tiny_pipeline
    base = ("--cores", "2", "--directory", str(wd), "-n", "--config", f"scenes={wd / 'scenes.tsv'}")
    proc = run_snakemake(*base)
    assert proc.returncode == 0 and "Nothing to be done" in proc.stdout + proc.stderr, proc.stderr[-3000:]
    proc = run_snakemake(*base, "export={formats: [inceventgs]}")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert planned_jobs(out) == {"all": 1, "export": 1}, out[-3000:]
    assert "results/tiny/export/inceventgs/mini00_medium" in out
