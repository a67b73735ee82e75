"""gs2e as a library outside the repository: a wheel built from the sources,
installed into a fresh virtual environment (dependencies reused from this one
through a .pth file, the repository's editable gs2e not importable), validates a
config and simulates events from a directory outside the repository."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import REPO, run_group


def run(cmd: list, cwd: Path, env: dict, timeout: float = 600) -> subprocess.CompletedProcess:
    return run_group([str(c) for c in cmd], cwd, env, timeout)


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> tuple[Path, dict]:
    """(bin folder of a fresh venv holding only the gs2e wheel, its environment)."""
    tmp = tmp_path_factory.mktemp("install")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["GS2E_PROGRESS"] = "0"
    # build from a copy: setuptools writes build/ and *.egg-info beside the sources
    src = tmp / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(REPO / name, src / name)
    shutil.copytree(REPO / "gs2e", src / "gs2e", ignore=shutil.ignore_patterns("__pycache__"))
    proc = run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                "-w", tmp / "wheel", src], tmp, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    wheel = next((tmp / "wheel").glob("gs2e-*.whl"))

    venv = tmp / "venv"
    proc = run([sys.executable, "-m", "venv", "--without-pip", venv], tmp, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    py = venv / "bin" / "python"
    proc = run([py, "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp, env)
    site = Path(proc.stdout.strip())
    # the dependencies of this environment, as a plain path: its .pth files (the
    # editable gs2e among them) are not processed there
    (site / "deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    proc = run([sys.executable, "-m", "pip", "--python", py, "install", "--no-deps", "--no-index", "-q",
                wheel], tmp, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return venv / "bin", env


def test_wheel_holds_the_schemas_and_imports_from_the_venv(installed, tmp_path):
    bin_dir, env = installed
    proc = run([bin_dir / "python", "-c",
                "import json, gs2e, gs2e.config as c; "
                "print(json.dumps([gs2e.__file__, str(c.CONFIG_SCHEMA), c.CONFIG_SCHEMA.is_file()]))"],
               tmp_path, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    module, schema, exists = json.loads(proc.stdout)
    venv = bin_dir.parent
    assert Path(module).is_relative_to(venv) and Path(schema).is_relative_to(venv) and exists
    assert not Path(module).is_relative_to(REPO)


def test_config_validate_outside_the_repository(installed, tmp_path):
    bin_dir, env = installed
    (tmp_path / "scenes.tsv").write_text("scene_id\tlayout\tpath\toverrides\none\tdemo\t\tdemo.n_views=8\n")
    (tmp_path / "config.yaml").write_text("scenes: scenes.tsv\nsfm: {matcher: sequential}\n")
    proc = run([bin_dir / "gs2e", "config", "--validate", "config.yaml", "--print"], tmp_path, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "matcher: sequential" in proc.stdout and "theta_on:" in proc.stdout  # defaults filled in
    (tmp_path / "bad.yaml").write_text("scenes: scenes.tsv\nsfm: {matcher: sometimes}\n")
    proc = run([bin_dir / "gs2e", "config", "--validate", "bad.yaml"], tmp_path, env)
    assert proc.returncode == 2 and "sfm.matcher" in proc.stderr


def test_events_outside_the_repository(installed, tmp_path):
    """A few frames of a brightening gradient (.npy, linear) give events."""
    bin_dir, env = installed
    ramp = np.linspace(0.1, 0.9, 32, dtype=np.float32)[None, :].repeat(24, 0)
    frames = np.stack([ramp * (1 + 0.5 * k) for k in range(5)]).clip(0, 1)
    np.save(tmp_path / "frames.npy", frames)
    proc = run([bin_dir / "gs2e", "events", "frames.npy", "--fps", "1000", "-o", "out",
                "--set", "model=ideal", "--set", "preview=false"], tmp_path, env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    import h5py
    import hdf5plugin  # noqa: F401  (blosc, the default compression)

    with h5py.File(tmp_path / "out" / "events.h5") as f:
        n = len(f["events/t"])
        on = int(np.asarray(f["events/p"]).sum())
    assert n > 0 and on == n  # brighter everywhere: ON events only
