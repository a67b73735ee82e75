"""Event recordings whose header carries no width/height (many Prophesee EVK
files): the size comes from the camera the header names, else from
--width/--height, else a one-line error naming both ways out.

Runs on the real EVK recordings in ../shared/data/events (a Gen3 EVT2 and a
Gen4.1 EVT3 file, no size in either header)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gs2e.cli import main
from gs2e.common.errors import InputError
from gs2e.events.containers import camera_size
from gs2e.events.io import read_events
from tests.conftest import shared_data

GEN3 = ("prophesee_gen3_evt2.raw", (480, 640), 539_481)
GEN41 = ("prophesee_gen41_evt3.raw", (720, 1280), 219_596)


def test_camera_table_reads_plugin_names_and_generations():
    assert camera_size({"plugin_name": "hal_plugin_gen3_fx3"})[:2] == (640, 480)
    assert camera_size({"plugin_name": "hal_plugin_gen41_evk3"})[:2] == (1280, 720)
    assert camera_size({"plugin_name": "hal_plugin_imx636_evk4"})[:2] == (1280, 720)
    assert camera_size({"sensor_generation": "3.1"})[:2] == (640, 480)
    assert camera_size({"plugin_name": "hal_plugin_genx320_evk3"})[:2] == (320, 320)
    assert camera_size({"camera": "DVXplorer Lite"})[:2] == (320, 240)
    assert camera_size({"plugin_name": "hal_plugin_unknown"}) is None
    assert camera_size({}) is None


@pytest.mark.parametrize("name,shape,n", [GEN3, GEN41])
def test_evk_recordings_read_with_the_named_cameras_size(name, shape, n):
    ev, got = read_events(shared_data("events", name))
    assert got == shape and len(ev) == n
    assert int(ev.x.max()) < shape[1] and int(ev.y.max()) < shape[0]
    assert np.all(np.diff(ev.t) >= 0)


def _strip_camera(src, dst):
    """The recording with its plugin_name line removed: a header naming no camera."""
    data = src.read_bytes()
    lines, rest = [], data
    while rest.startswith(b"%"):
        line, _, rest = rest.partition(b"\n")
        if not line.startswith(b"% plugin_name"):
            lines.append(line)
    dst.write_bytes(b"\n".join(lines) + b"\n" + rest)
    return dst


def test_a_header_naming_no_camera_needs_width_and_height(tmp_path):
    raw = _strip_camera(shared_data("events", GEN3[0]), tmp_path / "nameless.raw")
    with pytest.raises(InputError, match="--width and --height") as exc:
        read_events(raw)
    assert "nameless.raw" in str(exc.value)
    ev, shape = read_events(raw, (640, 480))
    assert shape == (480, 640) and len(ev) == GEN3[2]
    # the CLI: one line, no output; then with the size it works
    out = tmp_path / "stats.json"
    assert main(["events-stats", str(raw), "-o", str(out)]) != 0 and not out.exists()
    assert main(["events-stats", str(raw), "--width", "640", "--height", "480", "-o", str(out)]) == 0
    assert json.loads(out.read_text())["stats"]["n_events"] == GEN3[2]
    assert main(["events-stats", str(raw), "--width", "640", "-o", str(out)]) != 0  # half a size


def test_calibrate_and_convert_a_sizeless_recording(tmp_path):
    src = shared_data("events", GEN41[0])
    preset = tmp_path / "gen41.yaml"
    assert main(["events-stats", str(src), "--write-preset", str(preset), "-o",
                 str(tmp_path / "s.json")]) == 0
    text = preset.read_text()
    assert "width: {value: 1280" in text and "height: {value: 720" in text and "gen41" in text
    out = tmp_path / "copy.aedat4"
    assert main(["events-convert", str(src), str(out)]) == 0
    ev, shape = read_events(out)
    assert shape == (720, 1280) and len(ev) == GEN41[2]


@pytest.mark.parametrize("name,shape,n", [GEN3, GEN41])
def test_the_reports_sim_to_real_section_reads_evk_recordings(name, shape, n):
    from gs2e.report.io import read_real_events

    ev, got, label = read_real_events(shared_data("events", name))
    assert got == shape and len(ev) == n and f"{shape[1]}x{shape[0]}" in label
