"""Rerun audit on the tiny full-pipeline run (the shared ``tiny_pipeline``
fixture): after changing one parameter of one stage, a dry run plans exactly
that stage's jobs and everything downstream of them, and nothing else.

What would run is read from ``snakemake --summary`` (a TSV: one row per output
with its rule, status and plan; ``update pending`` = would be rebuilt). One test
checks that it agrees with the job-stats table of ``snakemake -n``.

Keys set in the scene's ``overrides`` column (tests/conftest.py
TINY_OVERRIDES) win over ``--configfile``, so they are changed through a copy
of the scenes table (``--config scenes=<copy>``); the others through a
``--configfile``. A report-only key (``metrics`` section) reruns the scene
tables, the summary and the report, nothing upstream. Library edits rerun a
stage through its ``code_version`` param (tests/test_codeversion.py); the
end checks that every rule carries it.

Nothing here changes the fixture's outputs: dry runs only; change files are
written under each test's tmp_path.
"""

from __future__ import annotations

import csv
import re
import shutil
from pathlib import Path

import pytest

from tests.conftest import REPO, TINY_OVERRIDES, planned_jobs, run_snakemake

# The workflow's rules (one job each per scene, render/events one per trajectory)
# and the rules each one feeds.
FEEDS: dict[str, set[str]] = {
    "demo_scene": {"ingest"},
    "ingest": {"sfm"},
    "sfm": {"train", "trajectory", "model_gate", "gate"},
    "train": {"render", "events", "model_gate", "gate"},
    "trajectory": {"render", "events"},
    # events renders its own samples from the model: of the render section it
    # takes only what changes pixels (background, scale, backend; events.smk)
    "render": {"windows", "scene_metrics"},
    "events": {"windows", "scene_metrics", "gate"},
    # the quality gates read the SfM, training and event statistics (gs2e.dataset); the
    # model's gates come before anything is rendered from it
    "model_gate": {"render", "events"},
    "gate": set(),
    # the aligned event windows of a trajectory read its frames and events
    "windows": {"scene_metrics"},
    "scene_metrics": {"summary"},
    "summary": {"datasheet"},
    "datasheet": set(),
}
STAGE_RULES = set(FEEDS)
# Target-only rules that may be planned on top (rule `all` has no output; a
# terminal `report` depends on everything).
TERMINAL_RULES = {"all", "report"}


def downstream(*rules: str) -> set[str]:
    """The given rules and every rule that (transitively) consumes their output."""
    out, todo = set(), list(rules)
    while todo:
        r = todo.pop()
        if r not in out:
            out.add(r)
            todo.extend(FEEDS[r])
    return out


def test_downstream_closure():
    assert downstream("summary") == {"summary", "datasheet"}
    assert downstream("train") == {"train", "model_gate", "render", "events", "windows", "gate", "scene_metrics",
                                   "summary", "datasheet"}
    assert downstream("demo_scene") == STAGE_RULES


def sm_args(wd: Path, table: Path | None = None) -> tuple[str, ...]:
    return ("--cores", "2", "--directory", str(wd), "--config", f"scenes={table or wd / 'scenes.tsv'}")


def summary_rows(*args: str) -> list[dict[str, str]]:
    """Rows of ``snakemake --summary ARGS`` (output_file, date, rule, log-file(s), status, plan)."""
    proc = run_snakemake("--summary", *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("output_file\t"))
    rows = list(csv.DictReader(lines[start:], delimiter="\t"))
    assert rows and all(r["plan"] in ("update pending", "no update") for r in rows), proc.stdout[-2000:]
    return rows


def pending(rows: list[dict[str, str]]) -> dict[str, set[str]]:
    """{rule: outputs it would rebuild}."""
    out: dict[str, set[str]] = {}
    for r in rows:
        if r["plan"] == "update pending":
            out.setdefault(r["rule"], set()).add(r["output_file"])
    return out


def check_stage_rules(planned: set[str], expected: set[str]) -> None:
    assert planned & STAGE_RULES == expected, f"planned {sorted(planned)}, expected {sorted(expected)}"
    assert planned - STAGE_RULES <= TERMINAL_RULES, sorted(planned)


def own_params_changed(rows: list[dict[str, str]]) -> set[str]:
    """Stage rules whose own params changed, but scene_metrics (which takes the
    whole scene config, so any change)."""
    return {r["rule"] for r in rows if r["status"] == "params changed"} & STAGE_RULES - {"scene_metrics"}


def scenes_table(path: Path, rows: dict[str, str]) -> Path:
    """Write a scenes table of demo scenes {scene_id: overrides}."""
    body = "".join(f"{sid}\tdemo\t\t{ov}\n" for sid, ov in rows.items())
    path.write_text("scene_id\tlayout\tpath\toverrides\n" + body)
    return path


def tiny_overrides_with(**changes: str) -> str:
    """TINY_OVERRIDES with some of its keys given new values (section__key=value)."""
    items = dict(item.split("=", 1) for item in TINY_OVERRIDES.split(";"))
    for k, v in changes.items():
        key = k.replace("__", ".")
        assert key in items, f"{key} is not set by TINY_OVERRIDES: change it with --configfile"
        items[key] = v
    return ";".join(f"{k}={v}" for k, v in items.items())


# -- nothing changed ----------------------------------------------------------

def test_unchanged_config_reruns_nothing(tiny_pipeline):
    wd, args = tiny_pipeline
    proc = run_snakemake("-n", *args)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Nothing to be done" in proc.stdout + proc.stderr
    rows = summary_rows(*args)
    assert {r["rule"] for r in rows} >= STAGE_RULES
    assert pending(rows) == {}
    assert {r["status"] for r in rows} == {"ok"}


# -- one key of one stage changed (--configfile) ------------------------------

@pytest.mark.parametrize("change, changed", [
    ("demo: {seed: 3}", {"demo_scene"}),
    ("ingest: {max_side: 100}", {"ingest"}),
    ("sfm: {max_num_features: 4096}", {"sfm"}),
    ("trajectory: {velocity: '0.3*sin(t)+1.0'}", {"trajectory"}),
    ("render: {write_depth: false}", {"render"}),
    ("render: {background: [0.2, 0.2, 0.2]}", {"render", "events"}),
    ("events: {theta_mismatch_sigma: 0.01}", {"events"}),
    ("events: {sampling: {bound_fraction: 0.5}}", {"events"}),
    # a target sensor: events and frames through its camera, and (splat.max_side=auto)
    # training at the smallest size that covers it; ingest and SfM never see it, so
    # choosing a sensor cannot change which views register
    ("events: {sensor: davis346}", {"train", "render", "events"}),
    ("events: {sensor: imx636}", {"train", "render", "events"}),
    ("splat: {max_side: 100}", {"train"}),
    # seeds are derived per (scene, stage) from the global seed: sfm, train,
    # trajectory and events use one; demo (own demo.seed), ingest and render do not
    ("seed: 5", {"sfm", "train", "trajectory", "events"}),
], ids=lambda x: x if isinstance(x, str) else None)
def test_config_change_reruns_the_stage_and_downstream(tiny_pipeline, tmp_path, change, changed):
    wd, args = tiny_pipeline
    (tmp_path / "change.yaml").write_text(change + "\n")
    rows = summary_rows(*args, "--configfile", str(tmp_path / "change.yaml"))
    plan = pending(rows)
    check_stage_rules(set(plan), downstream(*changed))
    # the jobs whose own params changed are exactly the changed stages
    assert own_params_changed(rows) == changed


def test_report_key_change_reruns_only_tables_and_report(tiny_pipeline, tmp_path):
    wd, args = tiny_pipeline
    (tmp_path / "change.yaml").write_text("metrics: {preview_window_ms: 5}\n")
    rows = summary_rows(*args, "--configfile", str(tmp_path / "change.yaml"))
    plan = pending(rows)
    check_stage_rules(set(plan), downstream("scene_metrics"))  # the summary and the datasheet from it
    assert "report" in plan and own_params_changed(rows) == set()


# -- one key changed in the scene's overrides (scenes table) ------------------

@pytest.mark.parametrize("changes, changed", [
    ({"splat__max_iterations": "100", "splat__min_iterations": "100"}, {"train"}),
    ({"trajectory__mini_frames": "40"}, {"trajectory"}),
    ({"render__fps": "20"}, {"render"}),
    ({"events__theta_on": "0.25"}, {"events"}),
    ({"events__model": "voltmeter"}, {"events"}),
], ids=lambda x: ",".join(f"{k.replace('__', '.')}={v}" for k, v in x.items()) if isinstance(x, dict) else None)
def test_scene_override_change_reruns_the_stage_and_downstream(tiny_pipeline, tmp_path, changes, changed):
    wd, _ = tiny_pipeline
    table = scenes_table(tmp_path / "scenes.tsv", {"tiny": tiny_overrides_with(**changes)})
    rows = summary_rows(*sm_args(wd, table))
    check_stage_rules(set(pending(rows)), downstream(*changed))
    assert own_params_changed(rows) == changed


def test_new_speed_preset_adds_its_trajectory_jobs(tiny_pipeline, tmp_path):
    """A second preset (listed for rendering) reruns the trajectory stage and
    renders/simulates both trajectories (the existing one is rewritten)."""
    wd, _ = tiny_pipeline
    over = tiny_overrides_with(trajectory__speed_presets="[medium,strong]",
                               render__trajectories="[mini00_medium,base_strong]")
    rows = summary_rows(*sm_args(wd, scenes_table(tmp_path / "scenes.tsv", {"tiny": over})))
    plan = pending(rows)
    check_stage_rules(set(plan), downstream("trajectory"))
    for rule, folder in (("render", "frames"), ("events", "events")):
        assert plan[rule] == {f"results/tiny/{folder}/mini00_medium", f"results/tiny/{folder}/base_strong"}
    status = {r["output_file"]: r["status"] for r in rows}
    assert status["results/tiny/frames/base_strong"] == "missing"
    assert status["results/tiny/events/base_strong"] == "missing"


def test_added_scene_leaves_the_existing_scene_alone(tiny_pipeline, tmp_path):
    """A second row in the scenes table plans every job of the new scene and the
    summary; the existing scene gets nothing beyond what moving its table costs."""
    wd, _ = tiny_pipeline
    moved = pending(summary_rows(*sm_args(wd, scenes_table(tmp_path / "same.tsv", {"tiny": TINY_OVERRIDES}))))
    moved_tiny = {rule for rule, outs in moved.items() if any(o.startswith("results/tiny/") for o in outs)}
    table = scenes_table(tmp_path / "two.tsv", {"tiny": TINY_OVERRIDES, "tiny2": TINY_OVERRIDES})
    plan = pending(summary_rows(*sm_args(wd, table)))
    tiny2 = {rule for rule, outs in plan.items() if any(o.startswith("results/tiny2/") for o in outs)}
    tiny = {rule for rule, outs in plan.items() if any(o.startswith("results/tiny/") for o in outs)}
    assert tiny2 == STAGE_RULES - {"summary", "datasheet"}
    assert tiny == moved_tiny
    assert plan["summary"] == {"results/summary.parquet"}
    assert plan["datasheet"] == {"results/datasheet.md"}


def test_same_table_elsewhere_reruns_nothing(tiny_pipeline, tmp_path):
    wd, _ = tiny_pipeline
    shutil.copy(wd / "scenes.tsv", tmp_path / "scenes.tsv")
    assert pending(summary_rows(*sm_args(wd, tmp_path / "scenes.tsv"))) == {}


def test_listing_another_trajectory_renders_only_that_one(tiny_pipeline, tmp_path):
    wd, _ = tiny_pipeline
    over = tiny_overrides_with(render__trajectories="[mini00_medium,base_medium]")
    plan = pending(summary_rows(*sm_args(wd, scenes_table(tmp_path / "scenes.tsv", {"tiny": over}))))
    assert plan["render"] == {"results/tiny/frames/base_medium"}
    assert plan["events"] == {"results/tiny/events/base_medium"}


def test_summary_agrees_with_dry_run(tiny_pipeline, tmp_path):
    """The --summary plan and the job-stats table of -n name the same jobs."""
    wd, args = tiny_pipeline
    (tmp_path / "change.yaml").write_text("events: {theta_mismatch_sigma: 0.01}\n")
    extra = ("--configfile", str(tmp_path / "change.yaml"))
    proc = run_snakemake("-n", *args, *extra)
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = planned_jobs(proc.stdout)
    assert set(re.findall(r"^rule (\w+):", proc.stdout, flags=re.M)) == set(counts)
    plan = pending(summary_rows(*args, *extra))
    assert {r: len(o) for r, o in plan.items()} == {r: n for r, n in counts.items() if r != "all"}
    check_stage_rules(set(counts), downstream("events"))


# -- library code changes ------------------------------------------------------

def test_every_rule_carries_its_stage_code_version():
    """Each rule's params include code=code_version(<its stage>) (so an edit in
    the stage's sources changes its params and reruns it)."""
    expected = {"demo_scene": "demo", "ingest": "ingest", "sfm": "sfm", "train": "train",
                "trajectory": "trajectory", "render": "render", "events": "events",
                "scene_metrics": "metrics", "summary": "metrics", "report": "report",
                "windows": "windows", "export": "export"}
    found = {}
    for smk in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        for m in re.finditer(r"^rule (\w+):(.*?)(?=^rule |\Z)", smk.read_text(), flags=re.M | re.S):
            code = re.search(r'code=code_version\("(\w+)"\)', m[2])
            found[m[1]] = code[1] if code else None
    assert {r: found.get(r) for r in expected} == expected
