"""The video task on real recordings with APS frames (gs2e bench-real,
bench.real_video): the methods on slider_depth's real events and frames, bad
recordings failing early, the workflow job that runs them (and only it), and
the report's real-beside-synthetic table."""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import ConfigError
from tests.conftest import REPO, planned_jobs, run_cli, shared_data
from gs2e.testing import run_snakemake


def test_slider_depth_every_method_every_frame(tmp_path):
    """4 APS frames after the first x 5 methods; on this slow slider the events
    carry the first frame forward better than holding it (integration beats
    keyframe_held on every frame); the networks start from nothing."""
    out = tmp_path / "real.parquet"
    run_cli("bench-real", str(shared_data("slider_depth")), "--out", str(out), check=True)
    df = pd.read_parquet(out)
    assert list(df.columns) == ["recording", "method", "frame", "t_rel_s", "n_events", "psnr", "ssim",
                                "mse", "time_s"]
    assert set(df["recording"]) == {"slider_depth"} and sorted(set(df["frame"])) == [1, 2, 3, 4]
    assert list(dict.fromkeys(df["method"])) == ["integrate", "complementary", "pienet", "pienet_lite",
                                                 "keyframe_held"]
    psnr = df.pivot(index="frame", columns="method", values="psnr")
    assert (psnr["integrate"] > psnr["keyframe_held"]).all(), psnr
    assert np.isfinite(df["psnr"]).all() and (df["n_events"] > 0).all()
    # the events between consecutive frames add up to all events inside (0.0038 .. 0.174 s)
    assert df[df["method"] == "integrate"]["n_events"].sum() > 40_000


def test_learned_off_and_a_bad_recording(tmp_path):
    out = tmp_path / "real.parquet"
    cfg = json.dumps({"video_learned": []})
    run_cli("bench-real", str(shared_data("slider_depth")), "--out", str(out), "--config-json", cfg, check=True)
    assert set(pd.read_parquet(out)["method"]) == {"integrate", "complementary", "keyframe_held"}
    bad = tmp_path / "bad.parquet"
    proc = run_cli("bench-real", str(shared_data("slider_depth")), str(shared_data("events", "dvxplorer_sample.aedat4")),
                   "--out", str(bad))
    assert proc.returncode != 0 and "dvxplorer_sample.aedat4: 0 APS frames" in proc.stderr
    assert not bad.exists() and not list(tmp_path.glob(".bad*"))


def test_config_names_a_missing_recording(tmp_path):
    from gs2e.config import load_config

    with pytest.raises(ConfigError, match=r"bench.real_video\[1\]: .*nowhere does not exist"):
        load_config({"bench": {"real_video": [str(shared_data("slider_depth")), str(tmp_path / "nowhere")]}})


def test_workflow_runs_one_job_and_leaves_the_scene_jobs_alone(tmp_path):
    """bench.real_video adds one dataset-level job with the recordings as
    inputs; the scenes' bench commands do not change (their code and params
    do not depend on it), so setting it reruns nothing else."""
    scenes = tmp_path / "scenes.tsv"
    scenes.write_text("scene_id\tlayout\tpath\toverrides\nd\tdemo\t\tbench.tasks=[video];"
                      "render.trajectories=[base_mild]\n")
    rec = str(shared_data("slider_depth"))
    runs = {}
    for real in ([], [rec]):
        proc = run_snakemake("-n", "-p", "--cores", "2", "--directory", str(tmp_path), "--config",
                             f"scenes={scenes}", "results_dir=out", f"bench={{real_video: {json.dumps(real)}}}")
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[bool(real)] = proc.stdout
    assert "bench_real" not in planned_jobs(runs[False])
    assert planned_jobs(runs[True])["bench_real"] == 1
    block = next(b for b in runs[True].split("\n\n") if "rule bench_real:" in b)
    assert rec in block and "out/bench_real.parquet" in block

    def bench_cmds(text):
        return sorted(b[b.index("gs2e"):] for b in re.split(r"\n\n", text) if "rule bench:" in b)

    assert bench_cmds(runs[False]) == bench_cmds(runs[True]) != []


def test_report_sets_real_beside_synthetic():
    from gs2e.report.build import real_vs_synthetic

    bench = pd.DataFrame({"task": ["video"] * 3 + ["deblur"], "trajectory": ["base_mild", "base_strong",
                                                                            "mini00_medium", "base_mild"],
                          "preset": ["mild", "strong", "medium", "mild"], "method": ["integrate"] * 3 + ["edi"],
                          "psnr": [30.0, 20.0, 99.0, 25.0], "ssim": [0.9, 0.5, 1.0, 0.8]})
    real = pd.DataFrame({"recording": ["rec"] * 4, "method": ["integrate", "integrate", "keyframe_held",
                                                             "keyframe_held"],
                         "mse": [0.01, 0.001, 0.01, 0.01], "ssim": [0.6, 0.8, 0.5, 0.5]})
    t = real_vs_synthetic(bench, real)
    assert list(t.columns) == ["method", "gs2e mild", "gs2e strong", "real rec"]
    row = t.set_index("method")
    assert row.loc["integrate", "gs2e mild"] == "30.00 / 0.900"  # novel-view paths left out
    # PSNR pooled over the frames: mean MSE 0.0055
    assert row.loc["integrate", "real rec"] == f"{-10 * np.log10(0.0055):.2f} / 0.700"
    assert pd.isna(row.loc["keyframe_held", "gs2e mild"]) and row.loc["keyframe_held", "real rec"] == "20.00 / 0.500"
    only_real = real_vs_synthetic(None, real)
    assert list(only_real.columns) == ["method", "real rec"]


def test_make_demo_passes_the_shared_recordings():
    import subprocess

    out = subprocess.run(["make", "-n", "demo"], cwd=REPO, capture_output=True, text=True).stdout
    line = next(ln for ln in out.splitlines() if "snakemake" in ln)
    if shared_data("slider_depth").is_dir():
        assert "'bench={real_video: [" in line and "slider_depth" in line and "davis346_street_aps.aedat4" in line


def test_report_strips_by_speed_with_tasks_side_by_side():
    from pathlib import Path

    from gs2e.report.build import _by_speed

    files = [Path(f"bench/{t}/{n}.png") for t in ("video", "deblur", "recon3d")
             for n in ("base_strong", "mini00_medium", "base_mild", "base_medium")]
    got = [f"{p.parent.name}/{p.stem}" for p in sorted(files, key=_by_speed)]
    want = [f"{t}/{n}" for n in ("base_mild", "base_medium", "mini00_medium", "base_strong")
            for t in ("deblur", "recon3d", "video")]
    assert got == want
