"""A dataset of many scenes (gs2e.dataset): quality gates, each scene's status
after a run with failures, the datasheet, and `gs2e dataset` end to end on a
real workflow run where one scene fails its gates and one its structure from
motion while the third passes."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import InputError
from gs2e.dataset.card import card_table, datasheet_markdown, provenance
from gs2e.dataset.gates import failed_gates, measure
from gs2e.dataset.settings import DatasetSettings
from gs2e.dataset.status import failed_jobs, read_snakemake_summary, scene_status, status_line, write_status
from gs2e.metrics.collect import summary
from tests.conftest import BIN, REPO, TINY_OVERRIDES


def _scene(d: Path, n_views=10, n_reg=8, psnr=25.0, ssim=0.8, runs=(("a", 1000, 10, 10),)):
    (d / "sfm").mkdir(parents=True)
    (d / "splat").mkdir()
    (d / "sfm" / "sfm_stats.json").write_text(json.dumps({"n_views": n_views, "n_registered": n_reg}))
    (d / "splat" / "train_stats.json").write_text(json.dumps(
        {"test_psnr": psnr, "test_ssim": ssim, "n_gaussians": 500}))
    for name, n, w, h in runs:
        (d / "events" / name).mkdir(parents=True)
        (d / "events" / name / "stats.json").write_text(json.dumps(
            {"stats": {"n_events": n, "width": w, "height": h}}))
    return d


# ------------------------------------------------------------------ gates

def test_measure_reads_the_stats_and_takes_the_least_events_per_pixel(tmp_path):
    d = _scene(tmp_path / "s", runs=(("a", 1000, 10, 10), ("b", 50, 10, 10)))
    v = measure(d, ["a", "b"])
    assert v["registered_fraction"] == pytest.approx(0.8)
    assert v["test_psnr_db"] == 25.0 and v["events_per_pixel"] == pytest.approx(0.5)
    assert v["n_events"] == 1050


def test_measure_never_passes_on_a_run_without_a_count(tmp_path):
    # NaN first or last: min() would depend on the order; the gate's value is missing either way
    for runs in ((("a", 1000, 10, 10), ("b", None, 10, 10)), (("b", None, 10, 10), ("a", 1000, 10, 10))):
        d = _scene(tmp_path / f"s{runs[0][0]}", runs=runs)
        assert math.isnan(measure(d, ["a", "b"])["events_per_pixel"])


def test_measure_names_a_missing_stats_file(tmp_path):
    d = _scene(tmp_path / "s")
    with pytest.raises(InputError, match="events/zz/stats.json"):
        measure(d, ["zz"])


def test_gates_pass_fail_and_missing():
    cfg = DatasetSettings.defaults(min_registered_fraction=0.8, min_test_psnr_db=20.0, min_events_per_pixel=1.0)
    good = {"registered_fraction": 0.8, "test_psnr_db": 20.0, "events_per_pixel": 1.0}
    assert failed_gates(good, cfg) == []  # at the threshold: passes
    bad = {"registered_fraction": 0.5, "test_psnr_db": 19.99, "events_per_pixel": 0.0}
    reasons = failed_gates(bad, cfg)
    assert len(reasons) == 3
    assert "registered views 50.0% < 80.0%" in reasons[0] and "dataset.min_registered_fraction" in reasons[0]
    assert "19.99 dB < 20.00 dB" in reasons[1]
    # a value that was not measured fails as missing, never passes
    reasons = failed_gates({**good, "test_psnr_db": math.nan}, cfg)
    assert reasons == ["held-out PSNR missing (dataset.min_test_psnr_db: 20.00 dB)"]
    # no threshold: not checked, whatever the value
    assert failed_gates(bad, DatasetSettings.defaults()) == []


def test_gate_thresholds_are_validated():
    from gs2e.common.errors import ConfigError

    with pytest.raises(ConfigError, match="dataset.min_registered_fraction"):
        DatasetSettings.defaults(min_registered_fraction=1.5)
    with pytest.raises(ConfigError, match="dataset.min_events_per_pixel"):
        DatasetSettings.defaults(min_events_per_pixel=-1)


# ------------------------------------------------------------------ status

def _log(d: Path, name: str, text: str):
    (d / "logs").mkdir(parents=True, exist_ok=True)
    (d / "logs" / f"{name}.log").write_text(text)


def test_failed_jobs_in_pipeline_order_with_their_one_line_errors(tmp_path):
    d = tmp_path / "s"
    _log(d, "ingest", "12:00 INFO gs2e: gs2e ingest finished in 1 s (1 CPU-s, peak RSS 10 MB)\n")
    _log(d, "export_flow_a", "gs2e export: error: flow export broke\n")
    _log(d, "sfm", "SIFT ...\ngs2e sfm: error: registered 3 of 20 views (15%) < sfm.min_registered_fraction\n")
    _log(d, "events_a", "simulating ...\nKilled\n")  # killed outright: its last line stands in
    jobs = failed_jobs(d / "logs")
    assert [j[1] for j in jobs] == ["sfm", "events_a", "export_flow_a"]
    assert jobs[0][2].startswith("registered 3 of 20 views")
    assert jobs[1][2] == "Killed"


def test_scene_status_from_snakemake_summary(tmp_path):
    root = tmp_path / "results"
    ok = _scene(root / "ok")
    (ok / "gate.json").write_text(json.dumps({"values": measure(ok, ["a"])}))
    bad = _scene(root / "bad", psnr=12.0)
    _log(bad, "model_gate", "gs2e gate: error: scene 'bad' fails its quality gates: held-out PSNR 12.00 dB < 20.00 dB\n")
    _log(bad, "sfm", "gs2e sfm finished in 1 s\n")
    late = root / "late"  # nothing ran, no log: interrupted
    late.mkdir(parents=True)
    rows = ["output_file\tdate\trule\tlog-file(s)\tstatus\tplan"]
    for sid in ("ok", "bad", "late"):
        for rel, rule in (("sfm", "sfm"), ("model_gate.json", "model_gate"), ("gate.json", "gate")):
            rows.append(f"{root / sid / rel}\t-\t{rule}\t{root / sid / 'logs' / (rule + '.log')}\tok\tno update")
    rows.append(f"{root / 'summary.parquet'}\t-\tsummary\t-\tmissing\tupdate pending")  # dataset-wide: ignored
    outs = read_snakemake_summary("\n".join(rows), root)
    assert list(outs) == ["ok", "bad", "late"] and len(outs["ok"]) == 3
    (ok / "model_gate.json").write_text("{}")
    t = scene_status(root, outs)
    assert list(t["status"]) == ["passed", "failed", "failed"]
    assert t.loc[1, "failed_stage"] == "model_gate" and "held-out PSNR 12.00 dB" in t.loc[1, "reason"]
    assert t.loc[1, "test_psnr_db"] == 12.0  # measured for the card, though it failed
    assert t.loc[2, "reason"].startswith("not finished:")
    line = status_line(t)
    assert line.startswith("dataset: 1 of 3 scenes passed, 2 failed: bad (model_gate: scene 'bad' fails")
    # many failures: the line names the first ten, the table has them all
    many = pd.concat([t.iloc[[1]]] * 12, ignore_index=True)
    assert status_line(many).endswith("; and 2 more (scene_status.parquet)")
    # the same table is not written again (its readers do not rerun)
    assert write_status(t, tmp_path / "st.parquet") and not write_status(t, tmp_path / "st.parquet")
    # a stale failed log of an output that exists is not the reason
    _log(ok, "train", "gs2e train: error: an old failure\n")
    assert scene_status(root, outs).loc[0, "status"] == "passed"


def test_summary_joins_the_status_and_keeps_failed_scenes_as_rows(tmp_path):
    a = pd.DataFrame({"scene_id": ["ok", "ok"], "trajectory": ["x", "y"], "train_test_psnr": [30.0, 30.0]})
    a.to_parquet(tmp_path / "ok.parquet")
    st = pd.DataFrame({"scene_id": ["ok", "bad"], "status": ["passed", "failed"],
                       "failed_stage": [None, "sfm"], "reason": [None, "registered 2 of 9 views"]})
    st.to_parquet(tmp_path / "st.parquet")
    s = summary([tmp_path / "ok.parquet"], tmp_path / "st.parquet")
    assert list(s["scene_id"]) == ["ok", "ok", "bad"]
    assert list(s["status"]) == ["passed", "passed", "failed"]
    assert s.loc[2, "fail_reason"] == "registered 2 of 9 views" and np.isnan(s.loc[2, "train_test_psnr"])
    # no tables at all: the failed scenes' rows alone (a passed scene without a table is not invented)
    assert list(summary([], tmp_path / "st.parquet")["scene_id"]) == ["bad"]
    # a table that is not a status table is named
    with pytest.raises(InputError, match="ok.parquet: not a scene status table"):
        summary([tmp_path / "ok.parquet"], tmp_path / "ok.parquet")


# ------------------------------------------------------------------ card

def test_provenance_read_from_the_input_folders(tmp_path):
    cap = tmp_path / "data" / "captures" / "cup"
    (cap / "images").mkdir(parents=True)
    (cap / "SOURCE.txt").write_text("source: github someone/cups @ abc\nwhat: a cup\nlicense: CC BY 4.0\n")
    assert provenance(cap / "images") == {"source": "github someone/cups @ abc", "terms": "CC BY 4.0",
                                          "from": str(cap / "SOURCE.txt")}
    other = tmp_path / "data" / "fern" / "images"
    other.mkdir(parents=True)
    (tmp_path / "data" / "SOURCES.md").write_text(
        "| folder | what | origin | terms |\n|---|---|---|---|\n"
        "| fern/images/ | 20 photos | LLFF (Mildenhall 2019) | research only |\n")
    p = provenance(other)
    assert p["source"] == "LLFF (Mildenhall 2019)" and p["terms"] == "research only"
    bare = tmp_path / "elsewhere"
    bare.mkdir()
    assert provenance(bare)["terms"] is None and provenance(None)["source"] is None


def test_datasheet_lists_scenes_sources_and_failures():
    summ = pd.DataFrame({"scene_id": ["ok", "ok", "bad"], "status": ["passed", "passed", "failed"],
                         "fail_reason": [None, None, "held-out PSNR 12 dB < 20 dB"],
                         "sfm_n_views": [10, 10, np.nan], "sfm_n_registered": [10, 10, np.nan],
                         "train_test_psnr": [28.0, 28.0, np.nan], "train_test_ssim": [0.9, 0.9, np.nan],
                         "train_n_gaussians": [1000, 1000, np.nan], "events_n_events": [5, 7, np.nan]})
    card = card_table(summ, None, {"ok": 3.5})
    assert list(card["scene_id"]) == ["ok", "bad"] and card.loc[0, "events"] == 12
    assert np.isnan(card.loc[1, "cpu_min"])
    md = datasheet_markdown(card, {"ok": {"layout": "folder", "path": "x", "source": "A | B", "terms": "CC0"},
                                   "bad": {"layout": "llff", "path": "y"}},
                            DatasetSettings.defaults(min_test_psnr_db=20.0))
    for q in ("## Motivation", "## Composition", "## Collection process", "## Uses", "## Distribution",
              "## Maintenance"):
        assert q in md
    assert "| ok | passed | 10 | 10 | 28.00 | 0.900 | 1000 | 12 | A / B | CC0 |" in md
    assert "CPU" not in md.split("### Scenes")[1].split("\n\n")[1]  # no run times: same data, same bytes
    assert "`bad` (held-out PSNR 12 dB < 20 dB)" in md and "not stated in the input folder" in md
    assert "`min_test_psnr_db` = 20" in md


# ------------------------------------------------------------------ end to end

def test_gs2e_dataset_finishes_the_good_scenes_and_reports_the_failed_ones(tmp_path):
    """Three tiny scenes through `gs2e dataset`: one passes; one fails its PSNR gate
    (a scene override sets it out of reach), so nothing is rendered from its model; one
    fails structure from motion (four views of noise). The good one is exported; the
    failed ones are not, and are rows with their reasons in scene_status, summary,
    report and datasheet; exit status 3."""
    rng = np.random.default_rng(0)
    noise = tmp_path / "noise"
    noise.mkdir()
    import cv2

    for i in range(4):
        cv2.imwrite(str(noise / f"{i:02d}.png"), rng.integers(0, 256, (64, 80, 3), dtype=np.uint8))
    tiny = TINY_OVERRIDES + ";export.formats=[imu]"
    (tmp_path / "scenes.tsv").write_text(
        "scene_id\tlayout\tpath\toverrides\n"
        f"good\tdemo\t\t{tiny}\n"
        f"blurry\tdemo\t\t{tiny};dataset.min_test_psnr_db=99\n"
        f"noise\tfolder\t{noise}\tsfm.matcher=exhaustive\n")
    (tmp_path / "dataset.yaml").write_text(
        "scenes: scenes.tsv\nresults_dir: results\ndataset:\n  min_registered_fraction: 0.8\n"
        "  min_test_psnr_db: 5.0\n")
    env = {**os.environ, "GS2E_PROGRESS": "0", "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    cmd = [sys.executable, "-m", "gs2e", "dataset", "--configfile", "dataset.yaml", "--cores", "2",
           "--", "--snakefile", str(REPO / "Snakefile")]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 3, proc.stderr[-3000:]
    line = proc.stdout.strip().splitlines()[-1]
    assert line.startswith("dataset: 1 of 3 scenes passed, 2 failed: blurry (model_gate: scene 'blurry' fails "
                           "its quality gates: held-out PSNR"), line
    assert "noise (sfm: " in line
    res = tmp_path / "results"
    st = pd.read_parquet(res / "scene_status.parquet").set_index("scene_id")
    assert st.loc["good", "status"] == "passed" and st.loc["noise", "failed_stage"] == "sfm"
    assert (res / "good" / "export" / "imu" / "mini00_medium").is_dir()
    assert not (res / "blurry" / "export").exists()  # failed its gate: not exported ...
    assert not (res / "blurry" / "events").exists()  # ... nor rendered or simulated
    assert (res / "blurry" / "splat" / "model.json").is_file()  # its model is kept for inspection
    assert (res / "good" / "gate.json").is_file() and (res / "good" / "model_gate.json").is_file()
    summ = pd.read_parquet(res / "summary.parquet")
    assert set(summ["scene_id"]) == {"good", "blurry", "noise"}
    assert summ.set_index("scene_id").loc["noise", "fail_reason"] == st.loc["noise", "reason"]
    sheet = (res / "datasheet.md").read_text()
    assert "| good | passed |" in sheet and "| noise | failed |" in sheet
    html = (res / "report.html").read_text()
    assert "Dataset card" in html and "Scene good" in html and "Scene noise" not in html
    # a second run changes nothing that passed and reports the same
    again = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
    assert again.returncode == 3 and again.stdout.strip().splitlines()[-1] == line


@pytest.mark.parametrize("with_config", [False, True])
def test_gs2e_dataset_plans_as_make_dataset_calls_it(tmp_path, with_config):
    """`make dataset`'s own call (no Snakemake arguments but the dry run, which is
    taken off) and one ending in --config, which takes every word after it: the
    targets and config files must still reach Snakemake as such."""
    (tmp_path / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\nmini\tdemo\t\t{TINY_OVERRIDES}\n")
    (tmp_path / "ds.yaml").write_text(f"scenes: {tmp_path / 'scenes.tsv'}\nresults_dir: {tmp_path / 'res'}\n")
    extra = ["--config", f"results_dir={tmp_path / 'res'}"] if with_config else []
    env = {**os.environ, "GS2E_PROGRESS": "0", "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    proc = subprocess.run([sys.executable, "-m", "gs2e", "dataset", "--configfile", "config/config.yaml",
                           str(tmp_path / "ds.yaml"), "--cores", "1", "--", "-n", *extra],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "model_gate" in proc.stdout and "train" in proc.stdout  # the plan of the scene's jobs
    assert not (tmp_path / "res").exists()  # a dry run writes nothing


def test_gs2e_dataset_plans_after_a_run_killed_outright(tmp_path):
    """A workflow killed with SIGKILL (a lost node, an OOM kill of Snakemake) leaves
    its running job marked incomplete and its locks; the job finishes as an orphan and
    writes its output. A plain `snakemake -n` then refuses to plan; `gs2e dataset -n`
    plans the job again, and the run itself stops at the locks with what to do."""
    (tmp_path / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\nmini\tdemo\t\t{TINY_OVERRIDES}\n")
    (tmp_path / "ds.yaml").write_text("scenes: scenes.tsv\nresults_dir: res\n")
    env = {**os.environ, "GS2E_PROGRESS": "0", "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    sm = [sys.executable, "-m", "snakemake", "--cores", "1", "--snakefile", str(REPO / "Snakefile")]
    proc = subprocess.Popen([*sm, "res/mini/source", "--configfile", "ds.yaml"], cwd=tmp_path, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log, out = tmp_path / "res" / "mini" / "logs" / "demo_scene.log", tmp_path / "res" / "mini" / "source"
    t0 = time.monotonic()
    while not log.exists() and time.monotonic() - t0 < 120:
        time.sleep(0.1)
    proc.kill()
    proc.wait()
    while not out.exists() and time.monotonic() - t0 < 240:
        time.sleep(0.2)
    assert out.is_dir() and list((tmp_path / ".snakemake" / "incomplete").iterdir())
    plain = subprocess.run([*sm, "scenes", "-n", "--configfile", "ds.yaml"], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=300)
    assert plain.returncode != 0 and "IncompleteFilesException" in plain.stdout + plain.stderr
    ours = subprocess.run([sys.executable, "-m", "gs2e", "dataset", "--configfile", "ds.yaml", "--cores", "1",
                           "--", "-n", "--snakefile", str(REPO / "Snakefile")],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert ours.returncode == 0, ours.stderr[-2000:]
    assert "demo_scene" in ours.stdout  # the killed job is planned again
    # the run itself stops at the killed run's locks, with what to do, before any job
    run = subprocess.run([sys.executable, "-m", "gs2e", "dataset", "--configfile", "ds.yaml", "--cores", "1",
                          "--", "--snakefile", str(REPO / "Snakefile")],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    msg = run.stdout + run.stderr
    assert run.returncode not in (0, 3) and "is locked" in msg and "snakemake --unlock" in msg, msg[-2000:]
    assert not (tmp_path / "res" / "mini" / "ingest").exists()
