"""Shared test fixtures: repository paths, real data location, CLI runners."""

from __future__ import annotations

import os

# Before torch/numba load OpenMP (see gs2e/__init__.py): spinning waits halve
# throughput on a shared 2-core machine.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
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


def run_cli(*args: str, cwd: Path | None = None, check: bool = False,
            env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    """Run ``python -m gs2e ARGS`` and capture output."""
    e = {**os.environ, "GS2E_PROGRESS": "0", **(env or {})}
    proc = subprocess.run([sys.executable, "-m", "gs2e", *args], cwd=cwd or REPO,
                          capture_output=True, text=True, env=e, timeout=timeout)
    if check and proc.returncode != 0:
        raise AssertionError(f"gs2e {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-4000:]}")
    return proc


def run_snakemake(*args: str, cwd: Path | None = None, timeout: float = 1500) -> subprocess.CompletedProcess:
    """Run the venv's snakemake with the repo's Snakefile."""
    e = {**os.environ, "GS2E_PROGRESS": "0",
         "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), *args]
    return subprocess.run(cmd, cwd=cwd or REPO, capture_output=True, text=True, env=e,
                          timeout=timeout)


@pytest.fixture
def repo() -> Path:
    return REPO
