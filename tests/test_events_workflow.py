"""The event stage in workflow mode: luminance rendered on demand from the
model along the trajectory; tile, adaptive and fixed sampling."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gs2e.config import load_config, section_json
from tests.conftest import run_cli
from gs2e.testing import plane_model, straight_trajectory


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("evscene")
    return plane_model(tmp), straight_trajectory(tmp, dx=0.3)


@pytest.mark.parametrize("mode", ["tile", pytest.param("adaptive", marks=pytest.mark.slow),
                                  pytest.param("fixed", marks=pytest.mark.slow)])
def test_events_from_rendered_trajectory(scene, tmp_path, mode):
    from gs2e.events.io import read_h5

    model, traj = scene
    cfg = load_config({"events": {"model": "ideal", "theta_on": 0.3, "theta_off": 0.3,
                                  "max_duration_s": 0.05,
                                  "sampling": {"mode": mode, "fixed_fps": 2000.0}}})
    out = tmp_path / "ev"
    proc = run_cli("events", "--model", str(model), "--trajectory", str(traj), "-o", str(out),
                   "--seed", "1", "--config-json", section_json(cfg, "events"),
                   "--background", "0.1,0.2,0.3")
    assert proc.returncode == 0, proc.stderr[-3000:]
    ev, meta = read_h5(out / "events.h5")
    assert len(ev) > 100, "a textured plane panning past the camera must produce events"
    assert np.all(np.diff(ev.t) >= 0) and ev.t.dtype == np.int64
    assert ev.x.max() < 64 and ev.y.max() < 48
    assert f"sampling ({mode})" in proc.stderr
    st = json.loads((out / "stats.json").read_text())["stats"]
    assert st["sampling_mode"] == mode and st["duration_s"] == pytest.approx(0.05)
    assert json.loads(meta["metadata"])["render"]["background"] == [0.1, 0.2, 0.3]


def test_workflow_mode_needs_both_model_and_trajectory(scene, tmp_path):
    model, _ = scene
    proc = run_cli("events", "--model", str(model), "-o", str(tmp_path / "ev"))
    assert proc.returncode == 2 and "--trajectory" in proc.stderr
    assert not (tmp_path / "ev").exists()
