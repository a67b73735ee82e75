"""End to end through Snakemake on the built-in demo scene (the defaults: 36
views at 320x240): generation, ingestion and SfM, where COLMAP must register
every view and recover the ground-truth cameras; then the rerun audit (nothing to do, and exactly the
affected jobs after a parameter change)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from gs2e.io.scene import read_scene
from gs2e.sfm.align import alignment_errors
from tests.conftest import run_snakemake

# COLMAP on all 36 demo views plus the rerun audit: minutes; the default tier covers the path with the tiny pipeline
pytestmark = pytest.mark.slow


TARGET = "results/demo/sfm"


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    wd = tmp_path_factory.mktemp("e2e")
    (wd / "scenes.tsv").write_text("scene_id\tlayout\tpath\toverrides\ndemo\tdemo\t\t\n")
    args = ("--cores", "2", "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}")
    proc = run_snakemake(TARGET, *args)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return wd, args


def test_outputs_and_logs(demo_run):
    wd, _ = demo_run
    res = wd / "results" / "demo"
    src, ing, sfm = read_scene(res / "source"), read_scene(res / "ingest"), read_scene(res / "sfm")
    assert len(src.frames) == 36 and len(ing.frames) == 36
    assert len(sfm.frames) == 36, "COLMAP must register every demo view"
    stats = json.loads((res / "sfm" / "sfm_stats.json").read_text())
    assert stats["registration_rate"] == 1.0 and stats["mean_reproj_error_px"] < 1.0
    # the demo has ground-truth cameras: the recovered ones match them
    gt = {f.name: f.c2w for f in ing.frames}
    err = alignment_errors(np.stack([f.c2w for f in sfm.frames]), np.stack([gt[f.name] for f in sfm.frames]))
    assert err["center_rmse_pct_extent"] < 2.0 and err["rot_max_deg"] < 1.0
    orbit_radius = src.extra["config"]["orbit_radius"]
    assert err["center_max"] < 0.02 * orbit_radius
    assert stats["n_points"] > 1500
    assert sfm.frames[0].camera.fx == pytest.approx(src.frames[0].camera.fx, rel=0.02)
    assert stats["gt_center_rmse_pct_extent"] == pytest.approx(err["center_rmse_pct_extent"], rel=1e-6)
    for rule in ("demo_scene", "ingest", "sfm"):
        log = (res / "logs" / f"{rule}.log").read_text()
        assert re.search(r"finished in [0-9.]+ s", log), f"{rule}.log lacks the timing line"
        bench = (res / "benchmarks" / f"{rule}.tsv").read_text().splitlines()
        assert bench[0].startswith("s\t") and len(bench) == 2


def test_unchanged_config_reruns_nothing(demo_run):
    wd, args = demo_run
    proc = run_snakemake("-n", TARGET, *args)
    assert proc.returncode == 0
    assert "Nothing to be done" in proc.stdout + proc.stderr


def _planned_rules(out: str) -> set[str]:
    return set(re.findall(r"^rule (\w+):", out, flags=re.M))


def _dry_run_with(wd: Path, args, change: str) -> set[str]:
    (wd / "change.yaml").write_text(change)
    proc = run_snakemake("-n", TARGET, "--configfile", str(wd / "change.yaml"), *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return _planned_rules(proc.stdout)


@pytest.mark.parametrize("change, rules", [
    ("sfm: {max_num_features: 4096}", {"sfm"}),
    ("ingest: {max_side: 200}", {"ingest", "sfm"}),
    ("demo: {seed: 3}", {"demo_scene", "ingest", "sfm"}),
    ("seed: 5", {"sfm"}),  # the sfm seed is derived from the global seed
])
def test_parameter_change_reruns_exactly_the_affected_jobs(demo_run, change, rules):
    wd, args = demo_run
    assert _dry_run_with(wd, args, change) == rules
