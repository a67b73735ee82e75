"""Stage code versions come from the import closure of each stage's command:
every gs2e module a stage really loads is covered (each stage's command is run
on the tiny pipeline's files and its sys.modules checked), and a new import is
covered the moment it is written (no hand-kept list)."""

from __future__ import annotations

import importlib.util
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gs2e.codeversion import STAGE_ENTRY, code_version, stage_modules
from gs2e.config import load_config, scene_config, scene_params_json, section_json
from gs2e.testing import SHARED_DATA
from tests.conftest import REPO, TINY_OVERRIDES, run_cli, shared_data

# What `python -m gs2e <command>` does for one stage, then the gs2e modules loaded.
# (gs2e.cli also imports the other stages' CLI modules to declare their
# subcommands; codeversion leaves those out, so the driver registers only this one.)
DRIVER = """
import argparse, importlib, json, sys
from gs2e.common.log import setup_logging
entry, out_json, *argv = sys.argv[1:]
parser = argparse.ArgumentParser(prog="gs2e")
importlib.import_module(entry.split(":")[0]).register(parser.add_subparsers(dest="command"))
args = parser.parse_args(argv)
setup_logging(False)
rc = args.func(args) or 0
with open(out_json, "w") as fh:
    json.dump(sorted(m for m in sys.modules if m.split(".")[0] == "gs2e"), fh)
sys.exit(rc)
"""


def stage_commands(wd: Path, out: Path) -> dict[str, list[str]]:
    """Each stage's command on the tiny pipeline's files (training: 4 steps)."""
    cfg = scene_config(load_config({}), {"scene_id": "tiny", "overrides": TINY_OVERRIDES})
    cfg["splat"].update({"max_iterations": 4, "min_iterations": 0, "eval_every": 2, "densify_from": 1,
                         "densify_every": 2, "densify_until": 4, "resolution_schedule": [[0, 2], [2, 1]]})
    cfg["export"]["eventnerf_fit"] = "pad"  # EventNeRF's loader hard-codes 346x260; the tiny frames are 128x96
    res = wd / "results"
    tiny, traj = res / "tiny", str(res / "tiny" / "trajectories" / "mini00_medium.npz")
    sec = lambda s: section_json(cfg, s)  # noqa: E731
    return {
        "demo": ["demo-scene", "--out", str(out / "source"), "--config-json", sec("demo")],
        "ingest": ["ingest", "--layout", "demo", "--src", str(tiny / "source"), "--out", str(out / "ingest"),
                   "--config-json", sec("ingest")],
        "sfm": ["sfm", "--scene", str(tiny / "ingest"), "--out", str(out / "sfm"), "--config-json", sec("sfm")],
        "train": ["train", "--scene", str(tiny / "sfm"), "--out", str(out / "splat"), "--config-json", sec("splat")],
        "trajectory": ["trajectory", "--scene", str(tiny / "sfm"), "--out", str(out / "traj"),
                       "--config-json", sec("trajectory")],
        "render": ["render", "--model", str(tiny / "splat"), "--trajectory", traj, "--out", str(out / "frames"),
                   "--config-json", sec("render")],
        "events": ["events", "--model", str(tiny / "splat"), "--trajectory", traj, "-o", str(out / "events"),
                   "--config-json", sec("events")],
        "metrics": ["metrics", "--scene-dir", str(tiny), "--scene-id", "tiny", "--trajectories", "mini00_medium",
                    "--config-json", scene_params_json(cfg), "--out", str(out / "metrics.parquet")],
        "report": ["report", "--results-dir", str(res), "--out", str(out / "report.html"), "--scenes", "tiny",
                   "--config-json", sec("metrics")],
        "windows": ["windows", "--frames", str(tiny / "frames" / "mini00_medium"),
                    "--events", str(tiny / "events" / "mini00_medium"), "--out", str(out / "windows.parquet")],
        # the tiny run's events (30 ms) cover no two frames: see _scene_with_longer_events
        "export": ["export", "--scene-dir", str(out / "scene"), "--trajectory", "mini00_medium",
                   "--format", "eventnerf", "--out", str(out / "export"), "--config-json", sec("export")],
        "bench": ["bench", "--task", "video", "--frames", str(tiny / "frames" / "mini00_medium"),
                  "--events", str(out / "scene" / "events" / "mini00_medium"),
                  "--windows", str(out / "scene" / "windows" / "mini00_medium.parquet"),
                  "--trajectory", traj, "--out", str(out / "bench.parquet"), "--png", str(out / "bench.png"),
                  "--config-json", sec("bench")],
        "bench_summary": ["bench-summary", str(out / "bench.parquet"), "--out", str(out / "bench_all.parquet")],
        # the dataset's rules: a scene's quality gates, the whole run's datasheet
        "gate": ["gate", "--scene-dir", str(tiny), "--scene-id", "tiny", "--runs", "mini00_medium",
                 "--out", str(out / "gate.json"), "--config-json", sec("dataset")],
        "datasheet": ["datasheet", "--summary", str(res / "summary.parquet"), "--scenes-table",
                      str(wd / "scenes.tsv"), "--out", str(out / "datasheet.md"), "--config-json", sec("dataset")],
        "bench_real": ["bench-real", str(SHARED_DATA / "slider_depth"), "--out", str(out / "bench_real.parquet"),
                       "--config-json", sec("bench")],
        # the real recording along its path through the tiny scene: only what runs matters here
        "sim2real": ["bench-sim2real", "--model", str(tiny / "splat"), "--scene", str(tiny / "sfm"),
                     "--recording", str(SHARED_DATA / "slider_depth"), "--out", str(out / "sim2real"),
                     "--events-json", sec("events"), "--config-json",
                     json.dumps({"sim2real_variants": ["ideal"], "sim2real_fit": [], "sim2real_fps": 500.0})],
    }


def _scene_with_longer_events(wd: Path, out: Path) -> None:
    """``out/scene``: the tiny run's scene folder with events over 0.25 s of
    mini00_medium and their windows table. Exporters need events that cover
    two consecutive frames (100 ms apart at the tiny run's 10 fps); the tiny run
    simulates 30 ms."""
    tiny, scene = wd / "results" / "tiny", out / "scene"
    scene.mkdir()
    for name in ("frames", "trajectories", "sfm", "splat"):
        (scene / name).symlink_to(tiny / name)
    cfg = scene_config(load_config({}), {"scene_id": "tiny", "overrides": TINY_OVERRIDES})
    events = {**cfg["events"], "max_duration_s": 0.25}
    ev_dir = scene / "events" / "mini00_medium"
    run_cli("events", "--model", str(tiny / "splat"), "--trajectory",
            str(tiny / "trajectories" / "mini00_medium.npz"), "-o", str(ev_dir),
            "--config-json", json.dumps(events), check=True)
    run_cli("windows", "--frames", str(tiny / "frames" / "mini00_medium"), "--events", str(ev_dir),
            "--out", str(scene / "windows" / "mini00_medium.parquet"), check=True)


@pytest.mark.parametrize("stage", list(STAGE_ENTRY))
def test_every_module_a_stage_loads_is_in_its_code_version(stage, tiny_pipeline, tmp_path):
    if stage in ("bench_real", "sim2real"):
        shared_data("slider_depth")  # skips without ../shared/data
    commands = stage_commands(tiny_pipeline[0], tmp_path)
    if stage in ("export", "bench", "bench_summary"):
        _scene_with_longer_events(tiny_pipeline[0], tmp_path)
    if stage == "bench_summary":  # a bench table to collect
        assert run_cli(*commands["bench"]).returncode == 0
    argv = commands[stage]
    loaded_json = tmp_path / "loaded.json"
    proc = subprocess.run([sys.executable, "-c", DRIVER, STAGE_ENTRY[stage], str(loaded_json), *argv],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**__import__("os").environ, "GS2E_PROGRESS": "0"})
    assert proc.returncode == 0, proc.stderr[-4000:]
    loaded = set(json.loads(loaded_json.read_text()))
    covered = set(stage_modules(stage))
    assert STAGE_ENTRY[stage].split(":")[0] in loaded
    assert loaded <= covered, f"{stage} loaded modules its code version misses: {sorted(loaded - covered)}"


def _package_copy(tmp_path: Path):
    """gs2e's .py files copied, with codeversion loaded from the copy."""
    pkg = tmp_path / "gs2e"
    shutil.copytree(REPO / "gs2e", pkg, ignore=shutil.ignore_patterns("__pycache__", "*.yaml"))
    spec = importlib.util.spec_from_file_location("codeversion_copy", pkg / "codeversion.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return pkg, mod


def test_a_new_import_is_covered_when_written(tmp_path):
    pkg, cv = _package_copy(tmp_path)
    before = {s: cv.code_version(s) for s in STAGE_ENTRY}
    assert before == {s: code_version(s) for s in STAGE_ENTRY}  # relative paths: a copy hashes the same
    # a new module nobody imports changes nothing
    (pkg / "common" / "fresh.py").write_text("X = 1\n")
    cv.code_version.cache_clear()
    assert {s: cv.code_version(s) for s in STAGE_ENTRY} == before
    # a function-level import of it in the sfm stage brings it into sfm's version only
    f = pkg / "sfm" / "align.py"
    f.write_text(f.read_text() + "\n\ndef _uses_fresh():\n    from gs2e.common import fresh\n    return fresh.X\n")
    cv.code_version.cache_clear()
    after = {s: cv.code_version(s) for s in STAGE_ENTRY}
    assert {s for s in STAGE_ENTRY if after[s] != before[s]} == {"sfm"}
    assert "gs2e.common.fresh" in cv.stage_modules("sfm")
    (pkg / "common" / "fresh.py").write_text("X = 2\n")
    cv.code_version.cache_clear()
    assert {s for s in STAGE_ENTRY if cv.code_version(s) != after[s]} == {"sfm"}
    # lazy imports through a table of module names count too (gs2e/trajectory/__init__.py)
    assert "gs2e.trajectory.stage" in cv.stage_modules("render")


def test_closure_follows_relative_and_package_imports(tmp_path):
    pkg, cv = _package_copy(tmp_path)
    (pkg / "demo" / "extra_a.py").write_text("from . import extra_b\nfrom .extra_c import f\n")
    (pkg / "demo" / "extra_b.py").write_text("")
    (pkg / "demo" / "extra_c.py").write_text("import gs2e.io.views as v\n\ndef f():\n    return v\n")
    mods = cv.import_closure(("gs2e.demo.extra_a",), pkg)
    assert {"gs2e", "gs2e.demo", "gs2e.demo.extra_b", "gs2e.demo.extra_c", "gs2e.io", "gs2e.io.views"} <= set(mods)
    assert mods["gs2e.demo.extra_c"] == pkg / "demo" / "extra_c.py"


def test_an_edit_reruns_the_stages_that_load_it(tmp_path):
    """Which stages an edit of one file reruns (the import closures as they are
    today; a static closure errs towards rerunning)."""
    pkg, cv = _package_copy(tmp_path)
    stages = list(STAGE_ENTRY)
    before = {s: cv.code_version(s) for s in stages}

    def edit_and_diff(rel: str) -> set[str]:
        f = pkg / rel
        f.write_text(f.read_text() + "\n# edited\n")
        cv.code_version.cache_clear()
        now = {s: cv.code_version(s) for s in stages}
        changed = {s for s in stages if now[s] != before[s]}
        before.update(now)
        return changed

    # the report reads event files with gs2e.events; the windows table reads them
    # with events/io.py, which loads the package
    # (the dataset table's per-task columns are the tasks' own, gs2e.bench.tasks: it
    # follows the task modules and reruns with them; a job of seconds; so does the
    # real recordings' job and the sim-to-real job, whose commands share the bench CLI
    # module's register(); sim-to-real renders and simulates, so it follows those too)
    assert edit_and_diff("events/__init__.py") == {"events", "report", "windows", "export", "bench",
                                                   "bench_summary", "bench_real", "sim2real"}
    # the event stage renders with gs2e.splat, not the render stage's code;
    # the windows table loads render/dataset.py (frames table), hence the
    # render package and, through it, the renderer
    assert edit_and_diff("splat/__init__.py") == {"train", "render", "events", "windows", "export", "bench",
                                                  "bench_summary", "bench_real", "sim2real"}
    assert edit_and_diff("render/__init__.py") == {"render", "windows", "export", "bench", "bench_summary", "bench_real",
                                                   "sim2real"}
    # one CLI module, two rules: each follows only its own command's imports
    assert edit_and_diff("export/run.py") == {"export"}
    assert edit_and_diff("export/windows.py") == {"windows", "export", "bench", "bench_summary", "bench_real",
                                                  "sim2real"}
    # the benchmark's two rules: the tasks and the dataset table
    assert edit_and_diff("bench/run.py") == {"bench"}
    assert edit_and_diff("bench/summary.py") == {"bench_summary"}
    assert edit_and_diff("sfm/__init__.py") == {"sfm"}
    assert edit_and_diff("demo/__init__.py") == {"demo"}
    # stages write their tables with metrics/table.py; the scene tables are metrics' own
    assert edit_and_diff("metrics/collect.py") == {"metrics"}
    assert edit_and_diff("metrics/table.py") == set(stages) - {"demo", "ingest", "trajectory", "gate"}
    # the quality gates read stats files only; the datasheet and the report show them
    assert edit_and_diff("dataset/gates.py") == {"gate", "datasheet", "report"}
    assert edit_and_diff("dataset/card.py") == {"datasheet", "report"}
    # the trajectory builders run in the stages that read trajectories, not in
    # those before: gs2e.config loads trajectory/velocity.py only, and the
    # package's lazy table of names runs only when a name is imported from it
    assert edit_and_diff("trajectory/trajectory.py") == {"trajectory", "render", "events", "windows",
                                                         "export", "bench", "bench_summary", "bench_real",
                                                         "sim2real"}
    # every command loads gs2e.config, which checks trajectory.velocity by parsing it
    for rel in ("common/__init__.py", "config.py", "trajectory/velocity.py"):
        assert edit_and_diff(rel) == set(stages)


def test_the_installed_pienet_version_is_part_of_the_learned_stages_versions(monkeypatch):
    """Another release of event-pienet (other weights) reruns the stages that
    import it, and no other; a stage's code version names nothing not installed."""
    import gs2e.codeversion as cv

    assert cv.stage_distributions("bench") == {"event-pienet": cv._dist_version("event-pienet")}
    assert cv.stage_distributions("sfm") == {}
    before = {s: cv.code_version(s) for s in STAGE_ENTRY}
    monkeypatch.setattr(cv, "_dist_version", lambda dist: "0.0.0-other")
    cv.code_version.cache_clear()
    try:
        after = {s: cv.code_version(s) for s in STAGE_ENTRY}
    finally:
        monkeypatch.undo()
        cv.code_version.cache_clear()
    changed = {s for s in STAGE_ENTRY if after[s] != before[s]}
    assert "bench" in changed and "bench_real" in changed
    assert not changed & {"ingest", "sfm", "train", "trajectory", "render", "events", "windows", "export"}
    assert cv._dist_version("surely-not-a-distribution-gs2e") == "absent"
