"""The Slurm profile (workflow/profiles/slurm).

* Without Slurm: a dry-run through the profile plans the demo jobs with the
  profile's resources (and more memory on a retry), with no Slurm command on PATH.
* With Slurm (`-m slurm`): a real one-node cluster is started with
  workflow/scripts/slurm_local.sh (installing Debian's slurm-wlm + munge when
  missing, which needs root and apt), the demo workflow runs through the
  profile up to SfM, the outputs and the Slurm side of each job are checked,
  and the daemons are stopped.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from gs2e.io.scene import read_scene
from tests.conftest import BIN, REPO, slurm_local, why_no_slurm_cluster

PROFILE = REPO / "workflow" / "profiles" / "slurm"
TARGET = "results/demo/sfm"
N_VIEWS = 24  # a reduced demo keeps the cluster run short
RULES = ("demo_scene", "ingest", "sfm")
# Commands through which the executor plugin talks to Slurm.
SLURM_COMMANDS = {"sinfo", "squeue", "sbatch", "srun", "scontrol", "sacct", "scancel",
                  "sacctmgr", "sshare", "salloc"}


def _workdir(wd: Path) -> list[str]:
    """A run directory with a one-scene table and the reduced demo config."""
    (wd / "scenes.tsv").write_text("scene_id\tlayout\tpath\toverrides\ndemo\tdemo\t\t\n")
    (wd / "small.yaml").write_text(f"demo: {{n_views: {N_VIEWS}}}\n")
    return ["--directory", str(wd), "--configfile", str(wd / "small.yaml"),
            "--config", f"scenes={wd / 'scenes.tsv'}"]


def _snakemake(args: list[str], env: dict, timeout_s: int) -> subprocess.CompletedProcess:
    # `timeout` (coreutils) as well as subprocess' own limit: a stuck status
    # check must end the run, and Snakemake must be able to cancel its jobs.
    cmd = ["timeout", "-k", "20", str(timeout_s), str(BIN / "snakemake"),
           "--snakefile", str(REPO / "Snakefile"), "--profile", str(PROFILE), *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env=env,
                          timeout=timeout_s + 60)


def _planned_resources(out: str) -> dict[str, dict[str, str]]:
    """rule -> {resource: value} from a dry-run's job listing (a group job's
    rules are listed indented below it)."""
    res = {}
    for rule, body in re.findall(r"^[ \t]*rule (\w+):\n(.*?)(?=^\S|\Z)", out, flags=re.M | re.S):
        m = re.search(r"^\s+resources: (.*)$", body, flags=re.M)
        if m:
            res[rule] = dict(kv.split("=", 1) for kv in m.group(1).split(", "))
    return res


@pytest.fixture
def path_without_slurm(tmp_path) -> str:
    """A PATH on which no Slurm command exists (as on a laptop)."""
    shadow = tmp_path / "bin"
    shadow.mkdir()
    for d in os.environ.get("PATH", "").split(os.pathsep):
        if not d or not Path(d).is_dir() or Path(d) == BIN:
            continue
        for exe in Path(d).iterdir():
            link = shadow / exe.name
            if exe.name not in SLURM_COMMANDS and not link.exists():
                link.symlink_to(exe)
    return f"{BIN}{os.pathsep}{shadow}"


@pytest.mark.parametrize("attempt, factor", [(1, 1), (2, 2)])
def test_dry_run_through_profile_without_slurm(tmp_path, path_without_slurm, attempt, factor):
    env = {**os.environ, "PATH": path_without_slurm, "GS2E_PROGRESS": "0"}
    env.pop("SLURM_CONF", None)
    assert shutil.which("sbatch", path=path_without_slurm) is None
    wd = tmp_path / "run"
    wd.mkdir()
    proc = _snakemake(["-n", "--attempt", str(attempt), TARGET, *_workdir(wd)], env, 120)
    assert proc.returncode == 0, proc.stderr[-4000:]
    out = proc.stdout + proc.stderr
    res = _planned_resources(out)
    assert set(res) == set(RULES), out[-3000:]
    # rules without their own resources get the profile's defaults, scaled by the attempt
    for rule in ("demo_scene", "ingest"):
        assert int(res[rule]["mem_mb"]) == 2000 * factor
        assert int(res[rule]["runtime"]) == 30 * factor
    # sfm keeps the resources written in its rule, and its threads are the
    # profile's CPUs per job (not the 1 core of a dry-run)
    assert int(res["sfm"]["mem_mb"]) >= 1000 and int(res["sfm"]["runtime"]) >= 10
    # the interpreter's name is whatever made the venv: python, python3, python3.11
    assert re.search(r"python[\d.]* -m gs2e sfm .*--threads 8 ", out)
    assert not (wd / "results").exists(), "a dry-run must not write outputs"


# ---------------------------------------------------------------- real cluster

def _cluster_env() -> dict:
    return {**os.environ, "GS2E_SLURM_DIR": os.environ.get("GS2E_SLURM_DIR", "/tmp/gs2e-slurm"),
            "GS2E_SLURM_PARTITION": "gs2e"}


@pytest.fixture(scope="module")
def cluster():
    reason = why_no_slurm_cluster()
    if reason:
        pytest.skip(f"no local Slurm cluster: {reason}")
    env = _cluster_env()
    was_running = slurm_local("status", env).returncode == 0
    try:
        t0 = time.monotonic()
        proc = slurm_local("start", env)
        start_s = time.monotonic() - t0
        assert proc.returncode == 0, f"slurm_local.sh start failed:\n{proc.stderr[-3000:]}"
        yield env, start_s
    finally:
        if not was_running:  # leave a cluster the user started alone
            stop = slurm_local("stop", env, 120)
            assert stop.returncode == 0, stop.stderr[-2000:]
            assert slurm_local("status", env).returncode != 0, "daemons still running after stop"


def _squeue_history() -> dict[str, tuple[str, str, str]]:
    """Slurm job id -> (state, partition, cpus) of jobs still known to slurmctld."""
    out = subprocess.run(["squeue", "-h", "-t", "all", "-o", "%i|%T|%P|%C"], capture_output=True,
                         text=True, check=True, timeout=30).stdout
    return {i: (s, p, c) for i, s, p, c in (ln.split("|") for ln in out.split())}


# A rule that needs ~1.4 GB (1.2 GB + the job's own Snakemake) but asks for
# 1000 MB on its first attempt: Slurm kills it for memory, and the profile's
# retries resubmit it with 2000 MB.
OOM_SNAKEFILE = """
rule big:
    output:
        "out.txt",
    resources:
        mem_mb=lambda wc, attempt: 1000 * attempt,
        runtime=5,
    shell:
        "python -c 'x = bytearray(1200 * 2**20); x[::4096] = bytes(len(x[::4096])); "
        "import time; time.sleep(3)' && echo {resources.mem_mb} > {output}"
"""


@pytest.fixture(scope="module")
def slurm_runs(cluster, tmp_path_factory):
    """The demo up to SfM and the memory-retry toy, run through the profile at
    the same time (the one node fits a 1-CPU toy job next to a demo job)."""
    env, start_s = cluster
    env = {**env, "GS2E_PROGRESS": "0",
           "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    oom = tmp_path_factory.mktemp("oom")
    (oom / "Snakefile").write_text(OOM_SNAKEFILE)
    toy = subprocess.Popen(
        ["timeout", "-k", "20", "400", str(BIN / "snakemake"), "--snakefile", str(oom / "Snakefile"),
         "--directory", str(oom), "--profile", str(PROFILE), "--cores", "1",
         "--slurm-keep-successful-logs"],
        cwd=oom, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        wd = tmp_path_factory.mktemp("demo")
        cores = str(os.cpu_count() or 1)  # threads per job must fit the one node
        t0 = time.monotonic()
        demo = _snakemake([TARGET, "--cores", cores, "--slurm-keep-successful-logs",
                           *_workdir(wd)], env, 600)
        run_s = time.monotonic() - t0
        toy_out, _ = toy.communicate(timeout=460)
    finally:
        if toy.poll() is None:
            toy.kill()
    print(f"\nslurm cluster start {start_s:.1f} s; demo to sfm through Slurm {run_s:.1f} s")
    return {"demo": (wd, demo.stdout + demo.stderr, demo.returncode),
            "oom": (oom, toy_out, toy.returncode), "history": _squeue_history()}


def _submitted(out: str) -> dict[str, str]:
    """Slurm job id -> rule, or ``group_<name>`` for a group job (the profile's
    job groups), from Snakemake's submission messages."""
    return {jid: (kind + "_" + name if kind == "group" else name) for jid, kind, name in re.findall(
        r"Job \S+ has been submitted with SLURM jobid (\d+) \(log: .*?/slurm_logs/(rule|group)_(\w+)/", out)}


@pytest.mark.slurm
@pytest.mark.slow
def test_demo_workflow_through_slurm(slurm_runs):
    wd, out, rc = slurm_runs["demo"]
    assert rc == 0, out[-5000:]
    res = wd / "results" / "demo"
    sfm = read_scene(res / "sfm")
    assert len(sfm.frames) == N_VIEWS, "COLMAP must register every demo view"
    stats = json.loads((res / "sfm" / "sfm_stats.json").read_text())
    assert stats["registration_rate"] == 1.0
    for rule in RULES:
        log = (res / "logs" / f"{rule}.log").read_text()
        assert re.search(r"finished in [0-9.]+ s", log), f"{rule}.log lacks the timing line"
        bench = (res / "benchmarks" / f"{rule}.tsv").read_text().splitlines()
        assert bench[0].startswith("s\t") and len(bench) == 2

    # The three sub-minute-to-minute jobs went through one sbatch (the profile's
    # job group `prep`: input and SfM): Snakemake names its Slurm job id, the
    # plugin kept the group's Slurm log with every rule of it, and slurmctld saw
    # the job complete in the requested partition.
    submitted = _submitted(out)
    # the plugin names a group job's log folder group_<group>_<its rules>
    assert len(submitted) == 1 and list(submitted.values())[0].startswith("group_prep"), out[-3000:]
    for job_id in submitted:
        logs = list((wd / ".snakemake" / "slurm_logs").glob(f"group_prep*/**/{job_id}.log"))
        assert len(logs) == 1, f"no Slurm log for group prep (job {job_id})"
        text = logs[0].read_text()
        assert "slurm-jobstep" in text and all(f"rule {rule}:" in text for rule in RULES), text[-2000:]
        state, partition, _ = slurm_runs["history"][job_id]
        assert state == "COMPLETED" and partition == "gs2e", (state, partition)


@pytest.mark.slurm
@pytest.mark.slow
def test_job_killed_for_memory_is_retried_with_more(slurm_runs):
    wd, out, rc = slurm_runs["oom"]
    assert rc == 0, out[-5000:]
    assert (wd / "out.txt").read_text().strip() == "2000", "the successful attempt is the 2nd"
    jobs = sorted(_submitted(out), key=int)
    assert len(jobs) == 2, out[-3000:]
    first, second = (slurm_runs["history"][j][0] for j in jobs)
    assert first != "COMPLETED" and second == "COMPLETED", (first, second)
    log = (wd / ".snakemake" / "slurm_logs" / "rule_big" / f"{jobs[0]}.log").read_text()
    assert "exceeded memory limit" in log, log[-2000:]
