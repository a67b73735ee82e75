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
import subprocess
import sys
from pathlib import Path

import pytest

# the runners and scenes the benchmarks share (re-exported for the tests)
from gs2e.testing import (BIN, REPO, TINY_OVERRIDES, run_group, run_snakemake,  # noqa: F401
                          run_tiny_pipeline, slurm_local, tiny_pipeline_args,
                          why_no_slurm_cluster)

SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(*parts: str) -> Path:
    """Path under ../shared/data, skipping the test when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"real data not available: {p} (../shared/data is absent)")
    return p


def run_cli(*args: str, cwd: Path | None = None, check: bool = False,
            env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """Run ``python -m gs2e ARGS`` and capture output."""
    e = {**os.environ, "GS2E_PROGRESS": "0", **(env or {})}
    proc = run_group([sys.executable, "-m", "gs2e", *args], cwd=cwd or REPO, env=e, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"gs2e {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    return proc


@pytest.fixture
def repo() -> Path:
    return REPO


def planned_jobs(out: str) -> dict[str, int]:
    """Jobs per rule from the first "Job stats:" table of Snakemake's output
    (Snakemake 9 prints it again after the job blocks)."""
    table = out.split("Job stats:", 1)[1].split("total", 1)[0]
    return {m[0]: int(m[1]) for m in re.findall(r"^(\w+)\s+(\d+)\s*$", table, flags=re.M)}


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
