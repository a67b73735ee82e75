"""Noise calibration from recordings (gs2e.events.stats.calibrate_noise): the
fitted background-activity rate, ON fraction and refractory period recover
known values of synthetic sensors within their intervals, the DVXplorer
recording gives its values, and `gs2e events-stats --write-preset` writes them
as a sensor preset."""

import json

import numpy as np
import pytest
import yaml

from gs2e.cli import main
from gs2e.events.models import Events
from gs2e.events.settings import event_settings
from gs2e.events.stats import calibrate_noise
from tests.conftest import shared_data


def _renewal(W, H, rate_hz, dead_us, dur_s, on_fraction, seed):
    """Every pixel fires independently: intervals dead_us + Exp(1 / rate_hz)."""
    rng = np.random.default_rng(seed)
    n_pix, dur_us = W * H, int(dur_s * 1e6)
    per = int(dur_s / (dead_us * 1e-6 + 1 / rate_hz) * 1.5) + 20
    # from t = 0: the first interval is the (memoryless) wait of a running pixel
    t = np.cumsum(dead_us + rng.exponential(1e6 / rate_hz, (n_pix, per)), axis=1)
    assert np.all(t[:, -1] > dur_us)  # enough intervals drawn to cover the span
    pix = np.broadcast_to(np.arange(n_pix)[:, None], t.shape)
    keep = t < dur_us
    t, pix = np.floor(t[keep]).astype(np.int64), pix[keep]
    o = np.argsort(t, kind="stable")
    t, pix = t[o], pix[o]
    return Events(t, (pix % W).astype(np.uint16), (pix // W).astype(np.uint16),
                  (rng.random(t.size) < on_fraction).astype(np.uint8))


def _inside(ci, value):
    return ci[0] <= value <= ci[1]


def test_background_rate_and_balance_of_a_noise_only_sensor():
    W, H, rate, window_us = 64, 48, 0.5, 1000
    ev = _renewal(W, H, rate, 0, 20.0, 0.3, seed=1)
    c = calibrate_noise(ev, (H, W), window_us=window_us, n_boot=500)
    # an independent pixel's event is isolated when none of its k neighbours
    # fires within +-window: probability exp(-k rate 2 window)
    k = np.full((H, W), 8)
    k[[0, -1], :] = 5
    k[:, [0, -1]] = 5
    k[[0, 0, -1, -1], [0, -1, 0, -1]] = 3
    dur_s = (ev.t[-1] - ev.t[0]) * 1e-6
    expect = rate * np.mean(np.exp(-k * rate * 2 * window_us * 1e-6)) * 20.0 / dur_s
    assert _inside(c["ba_rate_ci95_hz"], expect) and _inside(c["ba_rate_poisson_ci95_hz"], expect)
    assert c["ba_rate_hz"] == pytest.approx(expect, rel=0.02)
    assert _inside(c["on_fraction_ci95"], 0.3) and _inside(c["ba_on_fraction_ci95"], 0.3)
    assert c["suggested"]["shot_noise_rate_hz"] == c["ba_rate_hz"]
    # a wider support window counts fewer events as isolated
    assert calibrate_noise(ev, (H, W), window_us=100_000, n_boot=10)["ba_rate_hz"] < 0.9 * expect


@pytest.mark.parametrize("dead_us", [0, 1000])
def test_refractory_period_is_the_low_cutoff_of_the_intervals(dead_us):
    ev = _renewal(16, 16, 200.0, dead_us, 5.0, 0.5, seed=2)
    c = calibrate_noise(ev, (16, 16), n_boot=200)
    lo, hi = c["refractory_ci95_us"]
    # q = 1e-4 of intervals dead + Exp(5 ms) lies ~0.5 us above the dead time
    assert dead_us <= lo <= c["refractory_us"] <= hi <= dead_us + 5
    assert c["iei_min_us"] >= dead_us and c["n_iei"] > 200_000


def test_empty_and_tiny_recordings_give_nan_not_errors():
    c = calibrate_noise(Events.empty(), (4, 4))
    assert np.isnan(c["ba_rate_hz"]) and c["n_iei"] == 0 and c["suggested"] == {}
    one_pixel = Events(np.array([0, 10, 30]), np.zeros(3, np.uint16), np.zeros(3, np.uint16),
                       np.array([1, 0, 1], np.uint8))
    c = calibrate_noise(one_pixel, (4, 4), n_boot=20)
    assert c["iei_min_us"] == 10 and c["refractory_us"] == 10 and c["n_isolated"] == 3


def test_dvxplorer_recording():
    from gs2e.events.io import read_events

    ev, shape = read_events(shared_data("events", "dvxplorer_sample.aedat4"))
    c = calibrate_noise(ev, shape)
    assert c["ba_rate_hz"] == pytest.approx(0.5566, abs=5e-4)
    lo, hi = c["ba_rate_ci95_hz"]
    plo, phi = c["ba_rate_poisson_ci95_hz"]
    assert lo < plo < c["ba_rate_hz"] < phi < hi  # scene activity: wider than counting noise
    assert 0.5 < lo and hi < 0.62
    assert c["ba_on_fraction"] == pytest.approx(0.542, abs=1e-3)
    assert c["on_fraction"] == pytest.approx(0.4915, abs=1e-4)
    # DVXplorer's readout scans the array every ~197 us: no pixel fires again sooner
    assert c["iei_min_us"] == 197 and c["refractory_us"] == 197
    assert c["refractory_ci95_us"] == [197, 197]


def test_cli_writes_the_sensor_preset(tmp_path, capsys):
    rec = shared_data("events", "dvxplorer_sample.aedat4")
    preset = tmp_path / "dvx.yaml"
    assert main(["events-stats", str(rec), "--write-preset", str(preset),
                 "--preset-name", "dvxplorer"]) == 0
    cal = json.loads(capsys.readouterr().out)["noise_calibration"]
    text = preset.read_text()
    assert text.startswith("# gs2e sensor preset measured from a real recording")
    p = yaml.safe_load(text)
    assert list(p) == ["name", "width", "height", "shot_noise_rate_hz", "shot_noise_on_fraction",
                       "refractory_us"]
    assert p["name"] == "dvxplorer"
    assert (p["width"]["value"], p["height"]["value"]) == (320, 240)
    for key, cal_key in (("shot_noise_rate_hz", "ba_rate_hz"), ("shot_noise_on_fraction", "ba_on_fraction"),
                         ("refractory_us", "refractory_us")):
        assert p[key]["value"] == pytest.approx(cal[cal_key], rel=1e-3)
        assert p[key]["ci95"][0] <= p[key]["value"] <= p[key]["ci95"][1]
        assert p[key]["source"] == f"measured from {rec}" and p[key]["method"]
    assert p["width"]["source"] == f"header of {rec}"
    # the file is a custom sensor as it stands: its values and sources reach the models
    from gs2e.config import load_config
    from gs2e.events.sensors import get_sensor, resolve_noise

    ev_cfg = load_config({"events": {"sensor": "custom", "sensor_file": str(preset)}})["events"]
    assert get_sensor(event_settings(ev_cfg)).size == (320, 240)
    vals, src = resolve_noise(event_settings(ev_cfg), 1.0)
    assert vals["shot_noise_rate_hz"] == p["shot_noise_rate_hz"]["value"]
    assert vals["refractory_us"] == p["refractory_us"]["value"]
    assert src["shot_noise_rate_hz"].endswith(f"measured from {rec}")
    # seeded bootstraps: the same recording gives the same file
    again = tmp_path / "again.yaml"
    assert main(["events-stats", str(rec), "--write-preset", str(again),
                 "--preset-name", "dvxplorer", "-o", str(tmp_path / "s.json")]) == 0
    assert again.read_text() == text


def test_cli_stats_of_a_converted_recording_match(tmp_path, capsys):
    rec = shared_data("events", "dvxplorer_sample.aedat4")
    assert main(["events-convert", str(rec), str(tmp_path / "r.raw")]) == 0
    assert main(["events-convert", str(tmp_path / "r.raw"), str(tmp_path / "r.h5")]) == 0
    capsys.readouterr()
    outs = []
    for f in (rec, tmp_path / "r.raw", tmp_path / "r.h5"):
        assert main(["events-stats", str(f)]) == 0
        outs.append(json.loads(capsys.readouterr().out))
    for o in outs[1:]:
        assert o["noise_calibration"] == outs[0]["noise_calibration"]
        assert {k: v for k, v in o["stats"].items() if k != "name"} == \
            {k: v for k, v in outs[0]["stats"].items() if k != "name"}
