"""Plug-ins that install without a fork: a toy package, installed by pip
into a folder of its own, adds a benchmark task, an export format, an event
model and a sensor preset through Python entry points, and gs2e's CLI,
config validation and workflow take them (docs/development.md's recipe)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from tests.conftest import REPO

TOY = '''
"""A gs2e plug-in: one of each kind."""
from gs2e.bench.tasks import Task
from gs2e.events.models import IdealModel
from gs2e.events.sensors import Sensor, Sourced
from gs2e.export.formats import Format

TASK = Task("toycount", "toy_gs2e:run_task")
FORMAT = Format("toytimes", "toy_gs2e:export_times", help="frame times as text")
SENSOR = Sensor("toycam", "a 64x48 toy sensor", Sourced(64, "toy"), Sourced(48, "toy"),
                Sourced(0.0, "toy"), Sourced(0.0, "toy"), Sourced(0.0, "toy"), Sourced(0.0, "toy"),
                Sourced(0.5, "toy"))


class ToyIdeal(IdealModel):
    """The ideal model under another name."""
    name = "toyideal"


def run_task(ds, cfg, user):
    import math
    rows = [{"method": "count", "frame": i, "t_us": int(t), "t_rel_s": 0.0, "motion_px": math.nan,
             "n_events": len(ds.events), "psnr": math.nan, "ssim": math.nan, "mse": math.nan,
             "theta": math.nan, "time_s": 0.0} for i, t in enumerate(ds.frames["t_us"])]
    img = ds.image("rgb", 0)
    return rows, {"sharp": img, "count": img}, 0


def export_times(src, out, cfg):
    out.text("times.txt", "".join(f"{t}\\n" for t in src.frames["t_us"]))
    out.manifest["target"] = "toy"
'''

PYPROJECT = '''
[build-system]
requires = ["setuptools"]
build-backend = "setuptools.build_meta"

[project]
name = "toy-gs2e"
version = "0.1"

[project.entry-points."gs2e.bench_tasks"]
toycount = "toy_gs2e:TASK"
[project.entry-points."gs2e.export_formats"]
toytimes = "toy_gs2e:FORMAT"
[project.entry-points."gs2e.event_models"]
toyideal = "toy_gs2e:ToyIdeal"
[project.entry-points."gs2e.sensors"]
toycam = "toy_gs2e:SENSOR"
'''


@pytest.fixture(scope="module")
def toy_site(tmp_path_factory):
    """The toy package installed by pip (no index, no build isolation) into a
    folder that stands in for site-packages; env puts it on the path."""
    tmp = tmp_path_factory.mktemp("toy")
    pkg = tmp / "toy"
    (pkg / "toy_gs2e").mkdir(parents=True)
    (pkg / "toy_gs2e" / "__init__.py").write_text(TOY)
    (pkg / "pyproject.toml").write_text(PYPROJECT)
    site = tmp / "site"
    proc = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--no-index",
                           "--no-build-isolation", "--target", str(site), str(pkg)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(site), str(REPO)]), "GS2E_PROGRESS": "0"}
    return site, env


def _gs2e(env, *args, cwd=None):
    return subprocess.run([sys.executable, "-m", "gs2e", *args], capture_output=True, text=True,
                          env=env, cwd=cwd, timeout=600)


def test_config_and_cli_know_the_plugins(toy_site, tmp_path):
    _, env = toy_site
    cfg = tmp_path / "c.yaml"
    cfg.write_text("bench: {tasks: [toycount]}\nexport: {formats: [toytimes]}\n"
                   "events: {model: toyideal, sensor: toycam}\n")
    proc = _gs2e(env, "config", "--validate", str(cfg))
    assert proc.returncode == 0, proc.stderr
    presets = _gs2e(env, "events-presets")
    assert presets.returncode == 0 and "toycam" in {s["name"] for s in json.loads(presets.stdout)["sensors"]}
    # without the plug-in installed, the same config names the unknown key
    bare = {**env, "PYTHONPATH": str(REPO)}
    proc = _gs2e(bare, "config", "--validate", str(cfg))
    assert proc.returncode == 2 and "bench.tasks" in proc.stderr


def test_plugins_run_through_gs2e(toy_site, tmp_path):
    """The format and the task on the tests' plane scene; events simulated by
    the plug-in's model."""
    _, env = toy_site
    code = textwrap.dedent(f"""
        import json, sys
        sys.path.insert(0, {str(REPO / 'tests')!r})
        from pathlib import Path
        from gs2e.cli import main
        from gs2e.testing import plane_model, straight_trajectory
        tmp = Path({str(tmp_path)!r})
        model, traj = plane_model(tmp), straight_trajectory(tmp, dx=0.6)
        sc = tmp / "scene"
        (sc / "trajectories").mkdir(parents=True)
        traj.rename(sc / "trajectories" / "pan.npz")
        traj = sc / "trajectories" / "pan.npz"
        assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(sc / "frames" / "pan"),
                     "--threads", "1", "--config-json", json.dumps({{"fps": 20.0, "min_coverage": 0.0}})]) == 0
        ev = {{"model": "toyideal", "theta_on": 0.3, "theta_off": 0.3, "preview": False, "max_duration_s": 0.2}}
        assert main(["events", "--model", str(model), "--trajectory", str(traj), "-o", str(sc / "events" / "pan"),
                     "--seed", "0", "--threads", "1", "--config-json", json.dumps(ev)]) == 0
        assert main(["windows", "--frames", str(sc / "frames" / "pan"), "--events", str(sc / "events" / "pan"),
                     "--out", str(sc / "windows" / "pan.parquet")]) == 0
        assert main(["export", "--scene-dir", str(sc), "--trajectory", "pan", "--format", "toytimes",
                     "--out", str(tmp / "exp")]) == 0
        assert main(["bench", "--task", "toycount", "--frames", str(sc / "frames" / "pan"), "--events",
                     str(sc / "events" / "pan"), "--windows", str(sc / "windows" / "pan.parquet"),
                     "--out", str(tmp / "b.parquet"), "--png", str(tmp / "b.png")]) == 0
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    import h5py
    import pandas as pd

    times = (tmp_path / "exp" / "times.txt").read_text().split()
    assert len(times) > 2
    with h5py.File(tmp_path / "scene" / "events" / "pan" / "events.h5") as f:
        assert "toyideal" in json.dumps({k: str(v) for k, v in f.attrs.items()})
    assert set(pd.read_parquet(tmp_path / "b.parquet")["method"]) == {"count"}


def test_the_workflow_plans_the_plugins(toy_site, tmp_path):
    _, env = toy_site
    scenes = tmp_path / "s.tsv"
    scenes.write_text("scene_id\tlayout\tpath\toverrides\n"
                      "d\tdemo\t\tbench.tasks=[toycount];export.formats=[toytimes];events.sensor=toycam\n")
    proc = subprocess.run([str(Path(sys.executable).parent / "snakemake"), "-n", "-p", "--cores", "1",
                           "--snakefile", str(REPO / "Snakefile"), "--directory", str(tmp_path),
                           "--config", f"scenes={scenes}"], capture_output=True, text=True, env=env,
                          timeout=600)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    assert "results/d/export/toytimes/base_medium" in proc.stdout
    assert "results/d/bench/toycount/base_medium.parquet" in proc.stdout
    assert "--sensor-size 64x48" in proc.stdout  # the plug-in sensor sizes the render jobs


def test_installing_a_plugin_changes_the_versions_of_the_stages_that_run_it(toy_site):
    from gs2e.codeversion import PLUGIN_REGISTRIES, STAGE_ENTRY
    from gs2e.common.registry import PLUGIN_GROUPS

    assert set(PLUGIN_REGISTRIES) == set(PLUGIN_GROUPS)
    _, env = toy_site
    code = "import json; from gs2e.codeversion import STAGE_ENTRY, code_version as v; " \
           "print(json.dumps({s: v(s) for s in STAGE_ENTRY}))"
    run = lambda e: json.loads(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,  # noqa: E731
                                              env=e, timeout=300).stdout)
    with_toy, without = run(env), run({**env, "PYTHONPATH": str(REPO)})
    changed = {s for s in STAGE_ENTRY if with_toy[s] != without[s]}
    assert {"bench", "export", "events"} <= changed  # (render gets a sensor size as its argument)
    assert not changed & {"ingest", "sfm", "trajectory", "demo"}
