"""Same config + seeds -> same bytes: the tiny pipeline run a second time in a
fresh directory reproduces the shared run (the ``tiny_pipeline`` fixture).

Every file under results/ is byte-identical (demo images, ingested and SfM
scenes, the splat model .ply, trajectories .npz, frame PNG/npz, events.h5,
parquet tables...), except:

- logs/ and benchmarks/ (wall-clock times by nature), and a report page
  (results/report*, which shows run times);
- the files that carry timings. They are equal once these keys/columns are
  dropped, and only these:

  * sfm/sfm_stats.json, sfm/metrics.parquet: ``time_undistortion_s``,
    ``time_writing_s``, ``time_total_s``
  * splat/train_stats.json, splat/metrics.parquet: ``train_time_s``,
    ``train_cpu_s``, ``time_scene_analysis_s``; splat/curve.parquet:
    ``train_time_s``, ``cpu_time_s``
  * frames/<t>/render_stats.json, frames/<t>/metrics.parquet: ``time_s``,
    ``frames_per_s``, ``renders_per_s``
  * events/<t>/stats.json, events/<t>/stats.parquet: ``simulate_s``,
    ``simulate_s_per_s`` and its split ``source_s``, ``model_s``, ``stats_s``,
    ``write_s``, ``close_s``
  * <scene>/metrics.parquet and summary.parquet: the same, prefixed with the
    stage (``sfm_time_total_s``, ``train_train_cpu_s``, ``render_time_s``,
    ``events_simulate_s`` ...; TABLE_TIMING below).

The scene tables also carry provenance: ``gs2e_version``, one
``code_version_<stage>`` per stage, ``config_hash`` (independent of where the
run lives) and ``seed_*``.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from gs2e.codeversion import STAGE_ENTRY, code_version
from gs2e.config import derive_seed
from tests.conftest import run_tiny_pipeline

# Timing keys of each stage's stats JSON / metrics parquet (path under results/).
_SFM = {"time_undistortion_s", "time_writing_s", "time_total_s"}
_TRAIN = {"train_time_s", "train_cpu_s", "time_scene_analysis_s"}
_RENDER = {"time_s", "frames_per_s", "renders_per_s"}
_EVENTS = {"simulate_s", "simulate_s_per_s", "source_s", "model_s", "stats_s", "write_s",
           "close_s"}
STAGE_TIMING = {
    "tiny/sfm/sfm_stats.json": _SFM,
    "tiny/sfm/metrics.parquet": _SFM,
    "tiny/splat/train_stats.json": _TRAIN,
    "tiny/splat/metrics.parquet": _TRAIN,
    "tiny/splat/curve.parquet": {"train_time_s", "cpu_time_s"},
    "tiny/frames/mini00_medium/render_stats.json": _RENDER,
    "tiny/frames/mini00_medium/metrics.parquet": _RENDER,
    "tiny/events/mini00_medium/stats.json": _EVENTS,
    "tiny/events/mini00_medium/stats.parquet": _EVENTS,
}
# ... and of the scene tables (results/<scene>/metrics.parquet, results/summary.parquet).
TABLE_TIMING = {
    "sfm_time_undistortion_s", "sfm_time_writing_s", "sfm_time_total_s",
    "train_train_time_s", "train_train_cpu_s", "train_time_scene_analysis_s",
    "render_time_s", "render_frames_per_s", "render_renders_per_s",
    *(f"events_{k}" for k in _EVENTS),
}
TABLES = ("tiny/metrics.parquet", "summary.parquet")


def _timing_keys(rel: str) -> set[str] | None:
    return TABLE_TIMING if rel in TABLES else STAGE_TIMING.get(rel)


def _drop(obj, keys: set[str]):
    if isinstance(obj, dict):
        return {k: _drop(v, keys) for k, v in obj.items() if k not in keys}
    if isinstance(obj, list):
        return [_drop(v, keys) for v in obj]
    return obj


def _files(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file()}


@pytest.fixture(scope="module")
def second_run(tmp_path_factory):
    wd, _ = run_tiny_pipeline(tmp_path_factory.mktemp("tiny_again"))
    return wd


def test_second_run_reproduces_every_output(tiny_pipeline, second_run):
    res_a, res_b = tiny_pipeline[0] / "results", second_run / "results"
    files = _files(res_a)
    assert files == _files(res_b)
    skipped = lambda rel: rel.split("/")[0] in ("logs", "benchmarks") or "/logs/" in rel \
        or "/benchmarks/" in rel or rel.startswith("report")
    must = ["tiny/events/mini00_medium/events.h5", "tiny/trajectories/mini00_medium.npz",
            "tiny/splat/point_cloud/iteration_120/point_cloud.ply",
            "tiny/frames/mini00_medium/blur/000000.png"]
    assert set(must) <= files
    compared, with_timings = 0, set()
    for rel in sorted(files):
        if skipped(rel):
            continue
        a, b = res_a / rel, res_b / rel
        keys = _timing_keys(rel)
        if keys is None:
            assert a.read_bytes() == b.read_bytes(), f"{rel} differs between two identical runs"
        elif rel.endswith(".json"):
            ja, jb = json.loads(a.read_text()), json.loads(b.read_text())
            assert _drop(ja, keys) == _drop(jb, keys), rel
            with_timings.add(rel)
        else:
            da, db = pd.read_parquet(a), pd.read_parquet(b)
            assert keys <= set(da.columns), f"{rel}: timing columns {sorted(keys - set(da.columns))} are gone"
            pd.testing.assert_frame_equal(da.drop(columns=sorted(keys)), db.drop(columns=sorted(keys)),
                                          check_exact=True, obj=rel)
            with_timings.add(rel)
        compared += 1
    assert compared > 50
    # every timing entry above names a file of this run
    assert with_timings == set(STAGE_TIMING) | set(TABLES)


def test_scene_table_carries_code_versions_config_hash_and_seeds(tiny_pipeline, second_run):
    wd = tiny_pipeline[0]
    row = pd.read_parquet(wd / "results" / "summary.parquet").iloc[0]
    for stage in STAGE_ENTRY:
        assert row[f"code_version_{stage}"] == code_version(stage)
    assert row["code_version_trajectory"] == json.loads(
        (wd / "results/tiny/trajectories/trajectories.json").read_text())["code_version"]
    # the seeds the jobs were given: derived from the global seed (0) per scene and stage
    for stage in ("sfm", "train", "trajectory"):
        assert row[f"seed_{stage}"] == derive_seed(0, "tiny", stage)
    assert row["seed_events"] == derive_seed(0, "tiny/mini00_medium", "events")
    assert len(row["config_hash"]) == 16
    # the two runs' scenes tables live at different paths, same parameters: same hash
    other = pd.read_parquet(second_run / "results" / "summary.parquet").iloc[0]
    assert other["config_hash"] == row["config_hash"]
