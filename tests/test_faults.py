"""Fault injection: real workflow jobs killed with SIGKILL (what Slurm's memory
and time limits and the OOM killer do) at several points; the rerun must
complete with outputs byte-identical to an uninterrupted run and leave no
debris (no ``.<name>.tmp-*`` / ``.<name>.old-*``).

The uninterrupted run is the session's ``tiny_pipeline``; this test runs the
same workflow in another folder, one target at a time so that each kill lands
in the job it aims at:

1. training, mid-way (after its first held-out evaluation);
2. rendering, with frames already written into the output's temporary;
3. event simulation, with ``events.h5`` open in the output's temporary.

After each kill the killed job's temporary is checked to be there (the kill
hit a write in progress), and after the next run to be gone (the rerun swept
it). ``-m slow`` adds kills of every other rule and SIGTERM (cleaned at once).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import pytest

from tests.conftest import BIN, REPO, TINY_OVERRIDES, tiny_pipeline_args
from tests.test_reproducibility import _drop, _files, _timing_keys

SCENE = "tiny"
TRAJ = "mini00_medium"


def _children(pid: int) -> dict[int, list[int]]:
    kids: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
            except OSError:
                continue
            ppid = int(stat[stat.rfind(")") + 2:].split()[1])
            kids.setdefault(ppid, []).append(int(d.name))
    return kids


def _job_pid(root_pid: int, subcommand: str) -> int | None:
    """pid of the ``python -m gs2e <subcommand>`` process below ``root_pid``."""
    kids, todo = _children(root_pid), [root_pid]
    while todo:
        p = todo.pop()
        for c in kids.get(p, []):
            try:
                argv = Path(f"/proc/{c}/cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"gs2e" in argv and subcommand.encode() in argv:
                return c
            todo.append(c)
    return None


def temporaries(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*")
                  if ".tmp-" in p.name or ".old-" in p.name)


def _snakemake(wd: Path, *targets: str) -> subprocess.Popen:
    env = {**os.environ, "GS2E_PROGRESS": "0", "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    # targets first: tiny_pipeline_args ends with --config, which would take them as entries
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), *targets,
           *tiny_pipeline_args(wd)]
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


def run_and_kill(wd: Path, target: str, subcommand: str, ready, sig=signal.SIGKILL,
                 timeout_s: float = 600) -> str:
    """Run the workflow to ``target``; once ``ready()`` holds while the
    ``gs2e <subcommand>`` job runs, send it ``sig``. Returns Snakemake's output."""
    proc = _snakemake(wd, target)
    deadline, killed = time.time() + timeout_s, False
    try:
        while proc.poll() is None and time.time() < deadline:
            pid = _job_pid(proc.pid, subcommand)
            if pid is not None and ready():
                os.kill(pid, sig)
                killed = True
                break
            time.sleep(0.01)
        out, _ = proc.communicate(timeout=timeout_s)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert killed, f"the {subcommand} job ended before it could be killed:\n{out[-3000:]}"
    assert proc.returncode != 0, out[-3000:]
    return out


def run_to_end(wd: Path, *targets: str) -> str:
    proc = _snakemake(wd, *targets)
    out, _ = proc.communicate(timeout=1500)
    assert proc.returncode == 0, out[-5000:]
    return out


def assert_same_outputs(res_a: Path, res_b: Path) -> int:
    """Every file of two results trees equal (timing keys and logs aside, as in
    tests/test_reproducibility.py); returns the number of files compared."""
    import json

    import pandas as pd

    files = _files(res_a)
    assert files == _files(res_b), sorted(files ^ _files(res_b))
    n = 0
    for rel in sorted(files):
        if rel.split("/")[0] in ("logs", "benchmarks") or "/logs/" in rel or "/benchmarks/" in rel \
                or rel.startswith("report"):
            continue
        a, b = res_a / rel, res_b / rel
        keys = _timing_keys(rel)
        if keys is None:
            assert a.read_bytes() == b.read_bytes(), f"{rel} differs from the uninterrupted run"
        elif rel.endswith(".json"):
            assert _drop(json.loads(a.read_text()), keys) == _drop(json.loads(b.read_text()), keys), rel
        else:
            pd.testing.assert_frame_equal(pd.read_parquet(a).drop(columns=sorted(keys)),
                                          pd.read_parquet(b).drop(columns=sorted(keys)),
                                          check_exact=True, obj=rel)
        n += 1
    return n


def _has(folder: Path, pattern: str, at_least: int = 1) -> bool:
    return folder.is_dir() and sum(1 for _ in folder.glob(pattern)) >= at_least


def test_killed_jobs_rerun_to_identical_outputs_without_debris(tiny_pipeline, tmp_path):
    wd = tmp_path / "killed"
    wd.mkdir()
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\n{SCENE}\tdemo\t\t{TINY_OVERRIDES}\n")
    res = wd / "results"
    scene = res / SCENE
    log = []

    # 1. training, mid-way (its first held-out evaluation is logged at step 60)
    train_log = scene / "logs" / "train.log"
    run_and_kill(wd, f"results/{SCENE}/splat", "train",
                 lambda: train_log.exists() and "it 60:" in train_log.read_text())
    assert not (scene / "splat").exists()
    log.append(("train", temporaries(res)))

    # 2. rendering, with frames in the output's temporary
    frames_tmp = scene / "frames"
    run_and_kill(wd, f"results/{SCENE}/frames/{TRAJ}", "render",
                 lambda: _has(frames_tmp, f".{TRAJ}.tmp-*/rgb/*.png", 2))
    left = temporaries(res)
    assert any(t.startswith(f"{SCENE}/frames/.{TRAJ}.tmp-") for t in left), left
    log.append(("render", left))

    # 3. events, with events.h5 being written in the output's temporary
    events_tmp = scene / "events"
    run_and_kill(wd, f"results/{SCENE}/events/{TRAJ}", "events",
                 lambda: _has(events_tmp, f".{TRAJ}.tmp-*/.events.h5.tmp-*.h5"))
    left = temporaries(res)
    assert any(t.startswith(f"{SCENE}/events/.{TRAJ}.tmp-") for t in left), left
    assert not any(t.startswith(f"{SCENE}/frames/") for t in left), "rerun left render debris"
    log.append(("events", left))

    # the rerun: the plain workflow, to the end
    run_to_end(wd)
    assert temporaries(wd) == [], temporaries(wd)
    assert not (scene / ".splat.ckpt").exists()
    n = assert_same_outputs(tiny_pipeline[0] / "results", res)
    assert n > 50
    # nothing left to do: the rerun's outputs are complete and up to date
    dry = run_to_end(wd, "-n")
    assert "Nothing to be done" in dry, dry[-3000:]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_every_rule_killed_then_rerun(tiny_pipeline, tmp_path, sig):
    """Each job of the workflow killed once, as soon as it has started; SIGTERM
    must leave no temporary at all (cleaned like an exception)."""
    wd = tmp_path / "killed"
    wd.mkdir()
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\n{SCENE}\tdemo\t\t{TINY_OVERRIDES}\n")
    res = wd / "results"
    steps = [(f"results/{SCENE}/source", "demo-scene"), (f"results/{SCENE}/ingest", "ingest"),
             (f"results/{SCENE}/sfm", "sfm"), (f"results/{SCENE}/trajectories", "trajectory"),
             (f"results/{SCENE}/splat", "train"), (f"results/{SCENE}/frames/{TRAJ}", "render"),
             (f"results/{SCENE}/events/{TRAJ}", "events"), (f"results/{SCENE}/metrics.parquet", "metrics"),
             ("results/summary.parquet", "summary"), ("results/report.html", "report")]
    for target, sub in steps:
        started = time.time()
        run_and_kill(wd, target, sub, lambda: time.time() - started > 0 and True, sig=sig)
        if sig == signal.SIGTERM:
            assert temporaries(res) == [], (sub, temporaries(res))
        run_to_end(wd, target)
    run_to_end(wd)
    assert temporaries(wd) == []
    assert_same_outputs(tiny_pipeline[0] / "results", res)


def _snakemake_bare_path(wd: Path, *targets: str) -> subprocess.Popen:
    """.venv/bin/snakemake from a shell whose PATH lacks the venv (its ``python``
    is the system's, without gs2e's dependencies)."""
    env = {**os.environ, "GS2E_PROGRESS": "0", "PATH": "/usr/bin:/bin"}
    env.pop("VIRTUAL_ENV", None)
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), *targets,
           *tiny_pipeline_args(wd)]
    return subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)


@pytest.mark.slow
@pytest.mark.parametrize("subcommand,target,ready", [
    ("train", f"results/{SCENE}/splat", lambda scene: "it 60:" in _text(scene / "logs" / "train.log")),
    ("events", f"results/{SCENE}/events/{TRAJ}",
     lambda scene: _has(scene / "events", f".{TRAJ}.tmp-*/.events.h5.tmp-*.h5")),
])
def test_ctrl_c_stops_the_job_within_seconds_from_a_bare_shell(tmp_path, subcommand, target, ready):
    """SIGINT to Snakemake (Ctrl-C) while a job runs: the job process receives
    the signal and is gone within seconds with gs2e's one-line message, no
    temporary is left, and a rerun completes. Run from a shell without the
    venv on PATH: the jobs must still run gs2e's own interpreter."""
    wd = tmp_path / "ctrl_c"
    wd.mkdir()
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\n{SCENE}\tdemo\t\t{TINY_OVERRIDES}\n")
    scene = wd / "results" / SCENE
    proc = _snakemake_bare_path(wd, target)
    pid, deadline = None, time.time() + 900
    try:
        while proc.poll() is None and time.time() < deadline:
            pid = _job_pid(proc.pid, subcommand)
            if pid is not None and ready(scene):
                break
            time.sleep(0.05)
        assert pid is not None and proc.poll() is None, proc.communicate()[0][-3000:]
        t0 = time.time()
        os.kill(proc.pid, signal.SIGINT)
        while Path(f"/proc/{pid}").exists() and time.time() - t0 < 30:
            time.sleep(0.05)
        gone_s = time.time() - t0
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert gone_s < 10, f"the {subcommand} job ran on {gone_s:.0f} s after Ctrl-C"
    log = _text(scene / "logs" / f"{subcommand if subcommand == 'train' else 'events_' + TRAJ}.log")
    assert "terminated" in log.lower() or "interrupted" in log.lower(), log[-2000:]
    assert "Fatal Python error" not in log and "Traceback" not in log, log[-3000:]
    assert temporaries(wd / "results") == [], temporaries(wd / "results")
    proc = _snakemake_bare_path(wd, target)
    out, _ = proc.communicate(timeout=1500)
    assert proc.returncode == 0, out[-3000:]


def _text(path: Path) -> str:
    try:
        return path.read_text()
    except OSError:
        return ""
