"""The thread policy (gs2e.common.threads): the CPUs a process may use (affinity,
cgroup v1/v2 quota), -1/None = those CPUs and never more, an explicit
--threads wins over the config, torch and numba follow."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gs2e.common.threads import cgroup_cpu_quota, pick_threads, resolve_threads
from gs2e.config import load_config, scene_config, section_json
from tests.conftest import TINY_OVERRIDES, run_cli

N_CPUS = len(os.sched_getaffinity(0))
needs_two_cpus = pytest.mark.skipif(N_CPUS < 2 or shutil.which("taskset") is None,
                                    reason="needs 2 usable CPUs and taskset")

PROBE = """
import json, sys
import numba
if sys.argv[2] == "early":
    import torch
from gs2e.common.threads import available_cpus, set_threads
req = None if sys.argv[1] == "None" else int(sys.argv[1])
n = set_threads(req)
import torch  # "late": loaded after set_threads, it reads OMP_NUM_THREADS
print(json.dumps({"available": available_cpus(), "set": n, "torch": torch.get_num_threads(),
                  "numba": numba.get_num_threads()}))
"""


def probe(request: str, cpus: str | None = None, torch_import: str = "early") -> dict:
    """set_threads(request) in a fresh process, optionally pinned to ``cpus`` by
    taskset, with torch imported before it ("early") or after ("late")."""
    cmd = [sys.executable, "-c", PROBE, request, torch_import]
    if cpus is not None:
        cmd = ["taskset", "-c", cpus] + cmd
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@needs_two_cpus
@pytest.mark.parametrize("request_", ["None", "-1", "8"])
def test_affinity_limits_every_request(request_):
    """Pinned to one CPU, the default, -1 and an oversize count all give one
    thread in torch and numba (numba itself still sees every CPU)."""
    r = probe(request_, cpus="0")
    assert r == {"available": 1, "set": 1, "torch": 1, "numba": 1}


def test_explicit_count_and_default_unpinned():
    r = probe("1")
    assert (r["set"], r["torch"], r["numba"]) == (1, 1, 1)
    # set_threads does not import torch (the event stage on frames never loads it)
    r = probe("1", torch_import="late")
    assert (r["set"], r["torch"], r["numba"]) == (1, 1, 1)
    r = probe("None")
    assert r["available"] == N_CPUS and (r["set"], r["torch"]) == (N_CPUS, N_CPUS)


def test_resolve_and_pick():
    assert resolve_threads(None) == resolve_threads(-1) == resolve_threads(0) == N_CPUS
    assert resolve_threads(1) == 1 and resolve_threads(10 * N_CPUS) == N_CPUS
    assert pick_threads(None, 3) == 3 and pick_threads(2, 3) == 2 and pick_threads(-1, 3) == -1


def _fake_proc(tmp_path: Path, cgroup: str, mounts: list[str]) -> Path:
    proc = tmp_path / "proc_self"
    proc.mkdir()
    (proc / "cgroup").write_text(cgroup)
    (proc / "mountinfo").write_text("".join(mounts))
    return proc


def test_cgroup_v2_quota_takes_the_tightest_ancestor(tmp_path):
    root = tmp_path / "cg2"
    (root / "slurm" / "job_7").mkdir(parents=True)
    (root / "cpu.max").write_text("max 100000\n")
    (root / "slurm" / "cpu.max").write_text("400000 100000\n")
    (root / "slurm" / "job_7" / "cpu.max").write_text("150000 100000\n")
    line = f"41 31 0:38 / {root} rw,relatime - cgroup2 cgroup2 rw\n"
    proc = _fake_proc(tmp_path, "0::/slurm/job_7\n", [line])
    assert cgroup_cpu_quota(proc) == pytest.approx(1.5)
    (root / "slurm" / "job_7" / "cpu.max").write_text("max 100000\n")
    assert cgroup_cpu_quota(proc) == pytest.approx(4.0)  # the parent's limit binds
    (root / "slurm" / "cpu.max").write_text("max 100000\n")
    assert cgroup_cpu_quota(proc) is None


def test_cgroup_v1_cfs_quota(tmp_path):
    cpu = tmp_path / "cpu,cpuacct"
    (cpu / "docker" / "abc").mkdir(parents=True)
    for folder, quota in ((cpu, -1), (cpu / "docker" / "abc", 250000)):
        (folder / "cpu.cfs_quota_us").write_text(f"{quota}\n")
        (folder / "cpu.cfs_period_us").write_text("100000\n")
    mounts = [f"32 31 0:29 / {cpu} rw,relatime - cgroup cgroup rw,cpu,cpuacct\n",
              f"34 31 0:31 / {tmp_path / 'cpuset'} rw,relatime - cgroup cgroup rw,cpuset\n"]
    proc = _fake_proc(tmp_path, "3:cpuset:/\n2:cpu,cpuacct:/docker/abc\n0::/\n", mounts)
    assert cgroup_cpu_quota(proc) == pytest.approx(2.5)
    # a container that mounts its own cgroup as the hierarchy's root
    mounts[0] = f"32 31 0:29 /docker/abc {cpu / 'docker' / 'abc'} rw - cgroup cgroup rw,cpu,cpuacct\n"
    proc2 = tmp_path / "p2"
    proc2.mkdir()
    (proc2 / "cgroup").write_text("2:cpu,cpuacct:/docker/abc\n")
    (proc2 / "mountinfo").write_text("".join(mounts))
    assert cgroup_cpu_quota(proc2) == pytest.approx(2.5)
    assert cgroup_cpu_quota(tmp_path / "absent") is None


def test_sfm_threads_cli_wins_over_config(tiny_pipeline, tmp_path):
    """gs2e sfm records the threads it used: sfm.num_threads unless --threads
    is given; -1 = the CPUs the process may use (given poses and points: only
    undistortion runs, a few seconds)."""
    wd = tiny_pipeline[0]
    cfg = scene_config(load_config({}), {"scene_id": "tiny", "overrides": TINY_OVERRIDES})

    def threads_used(num_threads: int, *cli: str) -> int:
        c = {**cfg, "sfm": {**cfg["sfm"], "num_threads": num_threads}}
        out = tmp_path / f"sfm_{num_threads}_{'_'.join(cli) or 'default'}"
        run_cli("sfm", "--scene", str(wd / "results/tiny/ingest"), "--out", str(out),
                "--config-json", section_json(c, "sfm"), *cli, check=True)
        return json.loads((out / "sfm_stats.json").read_text())["threads"]

    assert threads_used(1) == 1
    assert threads_used(-1) == N_CPUS
    if N_CPUS >= 2:
        assert threads_used(1, "--threads", "2") == 2
