"""End-to-end proof that frames, blur and events agree.

A textured plane (a real 3DGS model of opaque Gaussians) seen by a camera
panning fast enough to blur by ~3 px over a 20 ms exposure, run through the
real stages (``gs2e render``, ``gs2e events`` with the ideal model and no
noise, ``gs2e windows``). EDI with the simulator's threshold must beat the
blurred frame on every frame, and its error against the sharp frame must fall
steadily as the threshold goes 0.4 -> 0.2 -> 0.1 -> 0.05 (events then
describe the exposure ever more finely). Each injected fault - the exposure
paired with the next frame's events, events late by half the exposure,
polarity flipped, blur averaged in sRGB instead of linear light - must break
that convergence: no unit test sees those.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from gs2e.cli import main

THETAS = (0.4, 0.2, 0.1, 0.05)
FPS, EXPOSURE_US = 40.0, 20_000.0
DURATION_S = 0.15


def _fast_pan(tmp: Path) -> Path:
    """The tests' straight pan over the plane, retimed to DURATION_S."""
    from gs2e.testing import straight_trajectory

    from gs2e.trajectory import load_trajectory
    from gs2e.trajectory.io import save_trajectory
    from gs2e.trajectory.trajectory import Trajectory

    d = load_trajectory(straight_trajectory(tmp, dx=1.2)).to_arrays()
    f = d["t_us"][-1] / (DURATION_S * 1e6)
    d["t_us"] = np.round(d["t_us"] / f).astype(np.int64)
    d["ds_dt"] = d["ds_dt"] * f
    path = tmp / "fast_pan.npz"
    save_trajectory(path, Trajectory.from_arrays(d))
    return path


def _render(model: Path, traj: Path, out: Path) -> None:
    cfg = {"fps": FPS, "exposure_us": EXPOSURE_US, "write_depth": False, "min_coverage": 0.0}
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(out),
                 "--threads", "1", "--config-json", json.dumps(cfg)]) == 0


def _events_and_windows(tmp: Path, model: Path, traj: Path, frames_dirs=("frames",)) -> None:
    for th in THETAS:
        ev = tmp / f"events_{th}"
        cfg = {"model": "ideal", "theta_on": th, "theta_off": th, "preview": False,
               "sampling": {"mode": "fixed", "fixed_fps": 4800.0}}
        assert main(["events", "--model", str(model), "--trajectory", str(traj), "-o", str(ev),
                     "--seed", "0", "--threads", "1", "--config-json", json.dumps(cfg)]) == 0
        for frames in frames_dirs:
            assert main(["windows", "--frames", str(tmp / frames), "--events", str(ev),
                         "--out", str(tmp / f"windows_{frames}_{th}.parquet")]) == 0


@pytest.fixture(scope="module")
def plane_dataset(tmp_path_factory):
    """frames/ (and frames_srgb/, blur averaged in sRGB), events and windows per theta."""
    import gs2e.render.dataset as RD
    from gs2e.testing import plane_model

    tmp = tmp_path_factory.mktemp("bench_plane")
    model = plane_model(tmp)
    traj = _fast_pan(tmp)
    _render(model, traj, tmp / "frames")
    # fault: the blur averaged on sRGB values (what a renderer without linear light does)
    # (the render stage's blur rules convert through gs2e.render.blur's colour functions)
    import gs2e.render.blur as RB

    mp = pytest.MonkeyPatch()
    mp.setattr(RD, "average_srgb", lambda frames: np.mean([np.clip(f, 0, 1) for f in frames], axis=0))
    mp.setattr(RB, "srgb_to_linear",
               lambda x, clip=False: np.clip(x, 0.0, 1.0) if clip else np.asarray(x, dtype=np.float64))
    mp.setattr(RB, "linear_to_srgb", lambda x: np.asarray(x, dtype=np.float64))
    try:
        _render(model, traj, tmp / "frames_srgb")
    finally:
        mp.undo()
    _events_and_windows(tmp, model, traj, ("frames", "frames_srgb"))
    return tmp


def _load(tmp: Path, th: float, frames: str = "frames"):
    from gs2e.bench.dataset import load_dataset

    return load_dataset("deblur", tmp / frames, tmp / f"events_{th}",
                        tmp / f"windows_{frames}_{th}.parquet")


def _late(ds, dt_us: float):
    """Events stamped ``dt_us`` late (the windows recomputed from their times)."""
    from gs2e.events.models import Events
    from gs2e.export.windows import compute_windows

    ev = ds.events
    t = ev.t + int(round(dt_us))
    w = compute_windows(ds.frames["t_us"].to_numpy(), ds.frames["exposure_us"].to_numpy(), t,
                        (ds.sim_span_us[0] + int(dt_us), ds.sim_span_us[1] + int(dt_us)))
    return replace(ds, events=Events(t, ev.x, ev.y, ev.p), windows=w)


def _flipped(ds):
    from gs2e.events.models import Events

    ev = ds.events
    return replace(ds, events=Events(ev.t, ev.x, ev.y, (1 - ev.p).astype(np.uint8)))


FAULTS = {
    "exposure paired with the next frame's events": lambda tmp, th: _late(_load(tmp, th), -1e6 / FPS),
    "events late by half the exposure": lambda tmp, th: _late(_load(tmp, th), EXPOSURE_US / 2),
    "polarity flipped": lambda tmp, th: _flipped(_load(tmp, th)),
    "blur averaged in sRGB": lambda tmp, th: _load(tmp, th, "frames_srgb"),
}


def edi_curve(datasets) -> list[dict]:
    """Per threshold: pooled grey PSNR of EDI (oracle) and of the blurred frame, and
    whether EDI beat the blurred frame on every frame with visible blur."""
    from gs2e.bench.deblur_task import run as run_deblur
    from gs2e.bench.run import resolve
    from gs2e.config import load_section

    cfg = resolve(load_section("bench"))
    out = []
    for ds in datasets:
        rows, _, _ = run_deblur(ds, cfg, {})
        by = {m: {r["frame"]: r for r in rows if r["method"] == m} for m in ("blurred", "edi_oracle")}
        # on luminance, what events measure (colour by ratio has a floor of its own)
        pooled = {m: -10 * math.log10(np.mean([r["mse_grey"] for r in v.values()])) for m, v in by.items()}
        visible = [f for f, r in by["blurred"].items() if r["motion_px"] > 1.0]
        out.append({"edi": pooled["edi_oracle"], "blurred": pooled["blurred"], "n": len(visible),
                    "wins": all(by["edi_oracle"][f]["psnr_grey"] > by["blurred"][f]["psnr_grey"]
                                for f in visible)})
    return out


def converges(curve: list[dict]) -> bool:
    """EDI beats the blur on every blurred frame at every threshold, and its
    PSNR rises by >= 2 dB at each halving of the threshold (threshold
    quantisation bounds its error: ~6 dB per halving until another error
    dominates)."""
    edi = [c["edi"] for c in curve]
    return (all(c["wins"] and c["n"] >= 3 for c in curve)
            and all(b - a >= 2.0 for a, b in zip(edi, edi[1:])))


def test_edi_converges_on_consistent_data(plane_dataset):
    curve = edi_curve([_load(plane_dataset, th) for th in THETAS])
    edi = [round(c["edi"], 2) for c in curve]
    assert converges(curve), f"EDI PSNR by theta {THETAS}: {edi}, blurred {curve[0]['blurred']:.2f}"
    assert curve[-1]["edi"] >= curve[-1]["blurred"] + 3.0, edi


def test_edi_converges_with_the_continuous_renderer(tmp_path):
    """The same proof for a model of the smooth window (issue 67): its sharp
    frames, blurred frames' sub-frames and event samples all come from the
    continuous renderer (depth orders cross-faded between knots)."""
    from gs2e.testing import plane_model

    model = plane_model(tmp_path)
    info = json.loads((model / "model.json").read_text())
    (model / "model.json").write_text(json.dumps({**info, "window": "smooth"}))
    traj = _fast_pan(tmp_path)
    _render(model, traj, tmp_path / "frames")
    _events_and_windows(tmp_path, model, traj)
    curve = edi_curve([_load(tmp_path, th) for th in THETAS])
    edi = [round(c["edi"], 2) for c in curve]
    assert converges(curve), f"EDI PSNR by theta {THETAS}: {edi}, blurred {curve[0]['blurred']:.2f}"
    assert curve[-1]["edi"] >= curve[-1]["blurred"] + 3.0, edi


def test_video_integration_converges(plane_dataset):
    """Direct integration from the first frame: the smaller the threshold, the
    closer to the sharp frames."""
    from gs2e.bench.dataset import load_dataset
    from gs2e.bench.run import resolve
    from gs2e.bench.video_task import run as run_video
    from gs2e.config import load_section

    cfg = resolve(load_section("bench"))
    psnr = []
    for th in THETAS:
        ds = load_dataset("video", plane_dataset / "frames", plane_dataset / f"events_{th}",
                          plane_dataset / f"windows_frames_{th}.parquet")
        rows, _, _ = run_video(ds, cfg, {})
        mse = [r["mse"] for r in rows if r["method"] == "integrate"]
        psnr.append(-10 * math.log10(np.mean(mse)))
    assert all(b - a >= 0.5 for a, b in zip(psnr, psnr[1:])), psnr


@pytest.mark.parametrize("fault", list(FAULTS))
def test_each_fault_breaks_convergence(plane_dataset, fault):
    curve = edi_curve([FAULTS[fault](plane_dataset, th) for th in THETAS])
    assert not converges(curve), (fault, [round(c["edi"], 2) for c in curve],
                                  [c["wins"] for c in curve])


def _bench_cli(tmp: Path, task: str, out: Path, *extra: str, frames: str = "frames", th: float = 0.2,
               events: Path | None = None, windows: Path | None = None) -> int:
    return main(["bench", "--task", task, "--frames", str(tmp / frames),
                 "--events", str(events or tmp / f"events_{th}"),
                 "--windows", str(windows or tmp / f"windows_{frames}_{th}.parquet"),
                 "--out", str(out / f"{task}.parquet"), "--png", str(out / f"{task}.png"),
                 "--threads", "1", *extra])


def test_cli_with_a_user_method_and_the_summary(plane_dataset, tmp_path):
    import bench_user_methods as U
    import imageio.v3 as iio

    from gs2e.metrics.table import read_table

    U.CALLS.clear()
    for task in ("deblur", "video"):
        assert _bench_cli(plane_dataset, task, tmp_path, "--method",
                          "bench_user_methods:mean_of_neighbours") == 0
    df = read_table(tmp_path / "deblur.parquet")
    assert set(df["method"]) == {"blurred", "edi_oracle", "edi_chosen",
                                 "bench_user_methods:mean_of_neighbours"}
    assert (df["motion_px"] > 1.0).all() and df["psnr"].notna().all()
    # the method saw each scored frame's exposure events, then each video frame's
    deblur_calls = [c for c in U.CALLS if c[0] == "deblur"]
    assert len(deblur_calls) == df["frame"].nunique() and all(c[2] > 0 for c in deblur_calls)
    assert all(c[4] - c[3] == pytest.approx(EXPOSURE_US) for c in deblur_calls)
    v = read_table(tmp_path / "video.parquet")
    assert set(v["method"]) == {"integrate", "complementary", "pienet", "pienet_lite", "keyframe_held",
                                "bench_user_methods:mean_of_neighbours"}
    # the reference: the keyframe held, which reconstruction from events must beat on a moving plane
    held, integ = (v[v["method"] == m].set_index("frame")["psnr"] for m in ("keyframe_held", "integrate"))
    assert (integ > held).all(), (integ, held)
    # the learned methods step through every frame, scored where the others are
    assert (v.groupby("method")["frame"].apply(tuple).nunique()) == 1
    strip = iio.imread(tmp_path / "deblur.png")
    assert strip.ndim == 3 and strip.shape[1] > 4 * 60
    assert main(["bench-summary", str(tmp_path / "deblur.parquet"), str(tmp_path / "video.parquet"),
                 "--out", str(tmp_path / "bench.parquet")]) == 0
    s = read_table(tmp_path / "bench.parquet")
    assert len(s) == 10 and set(s["task"]) == {"deblur", "video"}
    edi = s[(s["method"] == "edi_oracle")].iloc[0]
    blurred = s[(s["method"] == "blurred")].iloc[0]
    assert edi["psnr"] > blurred["psnr"]


def test_bad_inputs_are_one_line_errors_before_any_output(plane_dataset, tmp_path, capsys):
    from gs2e.export.windows import write_windows

    # a method that returns the wrong shape
    assert _bench_cli(plane_dataset, "deblur", tmp_path, "--method", "bench_user_methods:wrong_shape") == 2
    # a method that cannot be imported: refused before any frame is read
    assert _bench_cli(plane_dataset, "deblur", tmp_path, "--method", "no_such_mod_xyz:f") == 2
    # frames without blur
    _render_no_blur = {"fps": FPS, "exposure_us": EXPOSURE_US, "write_depth": False,
                       "min_coverage": 0.0, "write_blur": False}
    model, traj = plane_dataset / "model", plane_dataset / "fast_pan.npz"
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out",
                 str(tmp_path / "sharp_only"), "--config-json", json.dumps(_render_no_blur)]) == 0
    assert main(["bench", "--task", "deblur", "--frames", str(tmp_path / "sharp_only"), "--events",
                 str(plane_dataset / "events_0.2"), "--windows",
                 str(plane_dataset / "windows_frames_0.2.parquet"), "--out", str(tmp_path / "x.parquet"),
                 "--png", str(tmp_path / "x.png")]) == 2
    # events over 5 ms only: no exposure is covered
    cfg = {"model": "ideal", "theta_on": 0.2, "theta_off": 0.2, "preview": False, "max_duration_s": 0.005}
    assert main(["events", "--model", str(model), "--trajectory", str(traj), "-o",
                 str(tmp_path / "short_events"), "--config-json", json.dumps(cfg)]) == 0
    write_windows(plane_dataset / "frames", tmp_path / "short_events", tmp_path / "short.parquet")
    assert _bench_cli(plane_dataset, "deblur", tmp_path, events=tmp_path / "short_events",
                      windows=tmp_path / "short.parquet") == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.startswith("gs2e bench")]
    assert len(err) == 4, err
    assert "returned an image of shape (3, 3)" in err[0]
    assert "cannot import 'no_such_mod_xyz'" in err[1]
    assert "no blurred frames" in err[2]
    assert "nothing to deblur" in err[3] or "simulated events" in err[3]
    assert not list(tmp_path.glob("deblur.*")) and not (tmp_path / "x.parquet").exists()


def test_a_path_shorter_than_one_exposure_is_a_valid_run_with_nothing_to_deblur(plane_dataset, tmp_path):
    """Auto-exposure at night can lengthen the exposure past a short path: no
    frame can be scored, which is a valid result (an empty table, a strip that
    says so, the summary row missing), not an error."""
    import pandas as pd

    from gs2e.bench.summary import write_summary

    model, traj = plane_dataset / "model", plane_dataset / "fast_pan.npz"
    cfg = {"fps": 5.0, "exposure_us": 190_000.0, "write_depth": False, "min_coverage": 0.0}  # path 150 ms
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(tmp_path / "long"),
                 "--threads", "1", "--config-json", json.dumps(cfg)]) == 0
    assert main(["windows", "--frames", str(tmp_path / "long"), "--events", str(plane_dataset / "events_0.2"),
                 "--out", str(tmp_path / "long.parquet")]) == 0
    assert main(["bench", "--task", "deblur", "--frames", str(tmp_path / "long"), "--events",
                 str(plane_dataset / "events_0.2"), "--windows", str(tmp_path / "long.parquet"),
                 "--out", str(tmp_path / "d.parquet"), "--png", str(tmp_path / "d.png"), "--run", "pan@night"]) == 0
    assert len(pd.read_parquet(tmp_path / "d.parquet")) == 0 and (tmp_path / "d.png").stat().st_size > 0
    (tmp_path / "ok").mkdir()
    assert _bench_cli(plane_dataset, "deblur", tmp_path / "ok") == 0
    rows = write_summary([tmp_path / "d.parquet", tmp_path / "ok" / "deblur.parquet"], tmp_path / "s.parquet")
    assert len(rows) > 0 and all(r["task"] == "deblur" for r in rows)
