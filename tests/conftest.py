"""Shared test fixtures: repository paths, real data location, CLI runners."""

from __future__ import annotations

import os

# Before torch/numba load OpenMP (see gs2e/__init__.py): spinning waits halve
# throughput on a shared 2-core machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
# A fresh test run is dominated by cold numba compiles (minutes per kernel on a
# small machine). Tests compile at LLVM -O1, about 3x faster to compile; with
# fastmath off everywhere and no SVML, -O1 and -O3 give the same IEEE results
# (tests/test_numba_opt.py checks the bytes). They cache into their own folder so
# the pipeline's -O3 cache (gs2e/**/__pycache__) is never replaced by these.
os.environ.setdefault("NUMBA_OPT", "1")
os.environ.setdefault("NUMBA_CACHE_DIR", os.path.join(os.path.dirname(os.path.dirname(
    os.path.abspath(__file__))), ".numba-test-cache"))
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"
BIN = Path(sys.executable).parent


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data, skipping the test when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real data not available: {p} (../shared/data is absent)")
    return p


def run_group(cmd: list[str], cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    """``subprocess.run`` with captured text output, in a process group of its own
    that is killed whole on timeout or interrupt: Snakemake's job processes would
    otherwise outlive a timed-out test and slow every later one."""
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.communicate()
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def run_cli(*args: str, cwd: Path | None = None, check: bool = False,
            env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """Run ``python -m gs2e ARGS`` and capture output."""
    e = {**os.environ, "GS2E_PROGRESS": "0", **(env or {})}
    proc = run_group([sys.executable, "-m", "gs2e", *args], cwd=cwd or REPO, env=e, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"gs2e {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    return proc


def run_snakemake(*args: str, cwd: Path | None = None, timeout: float = 1500) -> subprocess.CompletedProcess:
    """Run the venv's snakemake with the repo's Snakefile."""
    e = {**os.environ, "GS2E_PROGRESS": "0",
         "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), *args]
    return run_group(cmd, cwd=cwd or REPO, env=e, timeout=timeout)


@pytest.fixture
def repo() -> Path:
    return REPO


SLURM_SCRIPT = REPO / "workflow" / "scripts" / "slurm_local.sh"


def slurm_local(action: str, env: dict, timeout_s: int = 300) -> subprocess.CompletedProcess:
    """workflow/scripts/slurm_local.sh start|stop|status (the one-node test cluster)."""
    return subprocess.run(["bash", str(SLURM_SCRIPT), action], capture_output=True, text=True,
                          env=env, timeout=timeout_s)


def why_no_slurm_cluster() -> str | None:
    """Why a local Slurm cluster cannot be started here, or None if it can."""
    if shutil.which("slurmctld") and shutil.which("munged"):
        return None if os.geteuid() == 0 else "starting slurmctld/slurmd needs root"
    if os.geteuid() != 0:
        return "slurm-wlm/munge are not installed and installing them needs root"
    if shutil.which("apt-get") is None:
        return "slurm-wlm/munge are not installed and apt-get is unavailable"
    return None


# The whole workflow on a tiny demo scene (16 views at 128x96, 120 training
# steps, one 30-frame trajectory, 30 ms of events): ~1 min on 2 cores. Run
# once per test session and shared read-only by the end-to-end, rerun-audit
# and report tests (they may dry-run in it, never change its outputs).
TINY_OVERRIDES = ";".join([
    "demo.n_views=16", "demo.width=128", "demo.height=96", "demo.supersample=1",
    "sfm.reuse_poses=true",
    "splat.max_iterations=120", "splat.min_iterations=120", "splat.eval_every=60",
    "splat.densify_from=40", "splat.densify_until=100", "splat.densify_every=20",
    "splat.resolution_schedule=[[0,2],[60,1]]", "splat.checkpoint_every=0",
    "trajectory.speed_presets=[medium]", "trajectory.mini_groups=1", "trajectory.mini_frames=30",
    # a slow mini-trajectory (~0.8 s): 9 frames at 10 fps, enough views for every export
    "trajectory.presets.medium.image_speed_width_s=0.3",
    "trajectory.plot=false",
    "render.trajectories=[mini00_medium]", "render.fps=10", "render.exposure_us=20000",
    "events.max_duration_s=0.03", "render.min_coverage=0.0",
    "events.model=ideal", "events.theta_on=0.3", "events.theta_off=0.3", "events.preview=false",
])


def planned_jobs(out: str) -> dict[str, int]:
    """Jobs per rule from the first "Job stats:" table of Snakemake's output
    (Snakemake 9 prints it again after the job blocks)."""
    table = out.split("Job stats:", 1)[1].split("total", 1)[0]
    return {m[0]: int(m[1]) for m in re.findall(r"^(\w+)\s+(\d+)\s*$", table, flags=re.M)}


def tiny_pipeline_args(wd: Path) -> tuple[str, ...]:
    return ("--cores", "2", "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}")


def run_tiny_pipeline(wd: Path, overrides: str = TINY_OVERRIDES) -> tuple[Path, tuple[str, ...]]:
    """Run the workflow to the summary in ``wd``; returns (wd, snakemake args)."""
    wd.mkdir(parents=True, exist_ok=True)
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\ntiny\tdemo\t\t{overrides}\n")
    args = tiny_pipeline_args(wd)
    proc = run_snakemake(*args, timeout=3600)  # cold numba caches on a slow machine: > 25 min
    assert proc.returncode == 0, proc.stderr[-5000:]
    return wd, args


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Tests on the shared tiny pipeline run are in the slow tier: with a cold
    numba cache the run takes over 20 min on a slow 2-core machine, where CI
    must finish in 90 (the default tier checks the stages one by one and the
    workflow by dry runs)."""
    for item in items:
        if "tiny_pipeline" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.slow)


@pytest.fixture(scope="session")
def tiny_pipeline(tmp_path_factory) -> tuple[Path, tuple[str, ...]]:
    return run_tiny_pipeline(tmp_path_factory.mktemp("tiny_pipeline"))
