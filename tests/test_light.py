"""Lighting conditions (gs2e.light), the frame camera (gs2e.render.camera),
events under the light, and colour event pixels: hard cases of each."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import ConfigError
from gs2e.light.curve import LightCurve, flicker
from gs2e.light.settings import Condition, LightSettings, run_names, split_run


def _cond(**over) -> Condition:
    base = dict(name="x", reference_lux=500.0, lux=500.0, ramp_to_lux=None, ramp_start=0.5,
                ramp_duration=0.0, flicker_hz=0.0, flicker_depth=0.0, flicker_waveform="sine")
    return Condition(**{**base, **over})


# ---------------------------------------------------------------- the light
@pytest.mark.parametrize("waveform", ["sine", "square", "rectified"])
@pytest.mark.parametrize("depth", [0.05, 0.3, 1.0])
def test_flicker_has_mean_one_and_its_percent_flicker(waveform, depth):
    t = (np.arange(200_000) + 0.5) / 200_000 / 100.0  # one period of 100 Hz, midpoints
    m = flicker(t, 100.0, depth, waveform)
    assert m.mean() == pytest.approx(1.0, abs=1e-6)
    assert m.min() >= -1e-12  # light is never negative, even at 100 % flicker
    assert (m.max() - m.min()) / (m.max() + m.min()) == pytest.approx(depth, rel=1e-4)


def test_ramp_is_c1_in_log_lux_and_reaches_its_ends():
    c = LightCurve(_cond(lux=500.0, ramp_to_lux=5.0, ramp_start=0.25, ramp_duration=0.5), 0, 1_000_000)
    t = np.linspace(0, 1e6, 100_001)
    e = np.log(c.lux(t))
    assert e[0] == pytest.approx(math.log(500)) and e[-1] == pytest.approx(math.log(5))
    assert np.all(np.diff(e) <= 1e-12)  # monotone
    slope = np.diff(e) / np.diff(t)
    # no kink: between samples 10 us apart the slope moves by under 1e-3 of its peak (a C0 ramp jumps by all of it)
    assert np.max(np.abs(np.diff(slope))) < 1e-3 * np.max(np.abs(slope))
    assert slope[:24_999].max() == 0 and abs(slope[25_001]) < 1e-8  # starts flat at ramp_start


@pytest.mark.parametrize("span", [(0.0, 20_000.0), (495_000.0, 515_000.0), (3_333.0, 4_444.0)])
def test_mean_scale_integrates_flicker_and_a_step(span):
    """Exposures over fractions of a flicker period, and across a step (a jump)."""
    for c in (_cond(flicker_hz=100.0, flicker_depth=0.8, flicker_waveform="rectified"),
              _cond(lux=50.0, ramp_to_lux=50_000.0, ramp_start=0.5, ramp_duration=0.0),
              _cond(lux=50.0, ramp_to_lux=5000.0, ramp_start=0.49, ramp_duration=0.02, flicker_hz=120.0,
                    flicker_depth=0.3, flicker_waveform="square")):
        curve = LightCurve(c, 0, 1_000_000)
        t = np.linspace(*span, 2_000_001)
        dense = float(np.mean(curve.scale(0.5 * (t[1:] + t[:-1]))))
        assert curve.mean_scale(*span) == pytest.approx(dense, rel=2e-4)


@pytest.mark.parametrize("over", [dict(flicker_hz=100.0, flicker_depth=0.3, flicker_waveform="sine"),
                                  dict(flicker_hz=120.0, flicker_depth=0.5, flicker_waveform="rectified"),
                                  dict(ramp_to_lux=50.0, ramp_start=0.2, ramp_duration=0.5),
                                  dict(ramp_to_lux=50.0, ramp_start=0.2, ramp_duration=0.5, flicker_hz=100.0,
                                       flicker_depth=0.2, flicker_waveform="sine")])
def test_light_rate_is_the_derivative_of_its_scale(over):
    """LightCurve.rate (the tangent pass's light term) against a central
    difference of scale over +-0.5 us, away from a rectified wave's kinks."""
    curve = LightCurve(_cond(**over), 0.0, 1e5)
    t = np.linspace(1000.0, 99_000.0, 997) + 0.37
    fd = (curve.scale(t + 0.5) - curve.scale(t - 0.5)) / 1.0
    rate = curve.rate(t)
    half = 0.5e6 / over.get("flicker_hz", 1.0)
    away = np.abs(((t / half) % 1.0) - 0.5) < 0.45  # not within 5 % of a half period of a kink
    assert np.abs(fd).max() > 1e-6
    np.testing.assert_allclose(rate[away], fd[away], rtol=1e-5, atol=1e-9 * np.abs(fd).max())


@pytest.mark.parametrize("over", [dict(flicker_hz=100.0, flicker_depth=0.3, flicker_waveform="square"),
                                  dict(ramp_to_lux=50.0, ramp_start=0.5, ramp_duration=0.0)])
def test_light_rate_has_no_jump_in_it(over):
    """A square wave's and a step's jumps have no rate, at the jump too
    (a difference across one would be the jump over its width)."""
    curve = LightCurve(_cond(**over), 0.0, 1e5)
    t = np.array([4_999.0, 5_000.0, 5_001.0, 50_000.0, 33_333.0])
    assert np.all(curve.rate(t) == 0.0)
    assert np.ptp(curve.scale(t)) > 0.1  # the jumps are there


def test_light_step_and_bound():
    curve = LightCurve(_cond(lux=50.0, ramp_to_lux=50_000.0, ramp_start=0.5, ramp_duration=0.0), 0, 2_000_000)
    assert curve.scale(np.array([999_999.0, 1_000_000.0])).tolist() == [0.1, 100.0]
    assert curve.max_step_us() is None and curve.max_scale() == pytest.approx(100.0)
    fl = LightCurve(_cond(flicker_hz=100.0, flicker_depth=0.3), 0, 1_000_000)
    assert fl.max_step_us() == pytest.approx(1e6 / 100 / 32) and not fl.constant
    assert fl.max_scale() == pytest.approx(1.3, rel=1e-6)


def test_condition_json_round_trip_and_errors():
    c = LightSettings.defaults().condition("flicker100")
    assert Condition.from_json(c.to_json()) == c
    with pytest.raises(ConfigError, match="keys differ"):
        Condition.from_json(json.dumps({"name": "x"}))
    with pytest.raises(ConfigError, match="no condition 'dusk'"):
        LightSettings.defaults().condition("dusk")
    with pytest.raises(ConfigError, match="light.runs"):
        LightSettings.defaults(runs=["dusk"])
    with pytest.raises(ConfigError, match="flicker_depth"):
        Condition.from_json(json.dumps({**json.loads(c.to_json()), "flicker_depth": 1.5}))


def test_runs_cross_trajectories_with_conditions():
    assert split_run("base_mild@dim") == ("base_mild", "dim") and split_run("a.b") == ("a.b", None)
    assert run_names(["base_mild", "mini00_medium@night"], ["dim", "night"]) == [
        "base_mild", "mini00_medium@night", "base_mild@dim", "base_mild@night"]


def test_config_refuses_a_run_under_an_unknown_condition_or_trajectory():
    from gs2e.config import load_config, scene_config

    with pytest.raises(ConfigError, match="render.trajectories"):
        load_config({"render": {"trajectories": ["base_medium@dusk"]}})
    cfg = load_config({"render": {"trajectories": ["base_fast@dim"]}})
    with pytest.raises(ConfigError, match="'base_fast' is not a trajectory"):
        scene_config(cfg, {"scene_id": "s", "layout": "demo", "path": "", "overrides": ""})


# ---------------------------------------------------------------- the frame camera
def _camera(**over):
    from gs2e.render.camera import FrameCamera
    from gs2e.render.settings import RenderSettings

    return FrameCamera.from_section({**RenderSettings.defaults().camera, "model": "sensor", **over})


@pytest.mark.parametrize("gain", [4.0, 16.0])
def test_photon_transfer_curve_matches_the_model(gain):
    """EMVA 1288's photon-transfer: a flat patch's DN variance against its mean
    is a line of slope K g (the inverse conversion gain) over the read-noise floor."""
    from gs2e.render.camera import capture, photon_transfer

    cam = _camera()
    rng = np.random.default_rng(5)
    E = 10_000.0
    levels = np.linspace(0.0, 0.8, 9) * cam.full_well_e / gain / (cam.sensitivity_e_per_s * E * 1e-6)
    means, vars_ = [], []
    for x in levels:
        dn, sat = capture(np.full((256, 256, 3), x), E, gain, cam, rng)
        assert not sat.any()
        means.append(dn.mean())
        vars_.append(dn.astype(np.float64).var())
    # slope: a fit weighted by each variance's own scatter (~ var sqrt(2 / N)); floor: the dark patch
    slope, _ = np.polyfit(np.array(means) - cam.black_level_dn, vars_, 1, w=1 / np.array(vars_))
    m_mean, m_var = photon_transfer(levels * cam.sensitivity_e_per_s * E * 1e-6, E * 1e-6, gain, cam)
    assert np.allclose(means, m_mean, rtol=0.005)
    assert slope == pytest.approx(cam.dn_per_e * gain, rel=0.05)
    assert vars_[0] == pytest.approx(m_var[0], rel=0.05)  # (K g)^2 (read^2 + dark) + 1/12
    assert np.allclose(vars_, m_var, rtol=0.05)


def test_saturation_and_a_black_frame_are_valid_frames():
    from gs2e.render.camera import capture, encode

    cam = _camera()
    rng = np.random.default_rng(0)
    dn, sat = capture(np.full((8, 8, 3), 100.0), 20_000.0, 1.0, cam, rng)
    # a full well at gain 1 fills the range; read noise after the well moves it by a DN or so
    assert sat.all() and (dn >= cam.dn_max - 2).all() and np.allclose(encode(dn, cam), 1.0, atol=0.005)
    dn, sat = capture(np.zeros((8, 8, 3)), 20_000.0, 1.0, cam, rng)
    assert not sat.any() and abs(dn.mean() - cam.black_level_dn) < 2  # read noise about the black level


def test_auto_exposure_settles_with_its_time_constant():
    from gs2e.render.camera import AutoExposure

    cam = _camera(ae_settling_s=0.1)
    ae = AutoExposure(cam, 20_000.0, 33_333.0)
    x = np.full((4, 4, 3), 0.5)
    ae.prime(x)
    assert ae.signal(x) == pytest.approx(cam.ae_target, rel=1e-9)
    total0 = ae.exposure_us * ae.gain
    bright = x * 4.0  # the light quadruples: the loop closes log(4) with time constant 0.1 s
    for _ in range(3):
        ae.update(ae.signal(bright), 1 / 30)
    left = math.log(ae.exposure_us * ae.gain / (total0 / 4))
    assert left == pytest.approx(math.log(4) * math.exp(-3 / 30 / 0.1), rel=1e-6)
    dark = AutoExposure(cam, 20_000.0, 33_333.0)
    dark.prime(np.zeros((4, 4, 3)))  # a black frame: as long and as loud as allowed, not a crash
    assert dark.exposure_us == 33_333.0 and dark.gain == cam.max_gain


# ---------------------------------------------------------------- frames and events of a model
@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    from gs2e.testing import plane_model, straight_trajectory

    tmp = tmp_path_factory.mktemp("light")
    return plane_model(tmp), straight_trajectory(tmp, dx=0.3)


def test_frames_under_a_light_step_through_the_camera(scene, tmp_path):
    from gs2e.render.dataset import render_dataset
    from gs2e.render.settings import RenderSettings

    model, traj = scene
    cfg = RenderSettings.defaults(fps=60.0, exposure_us=10_000.0, write_depth=False,
                                  camera={"model": "sensor", "ae_settling_s": 0.05})
    hdr = LightSettings.defaults().condition("hdr")
    render_dataset(model, traj, tmp_path / "a", cfg, light=hdr, seed=7)
    render_dataset(model, traj, tmp_path / "b", cfg, light=hdr, seed=7)
    df = pd.read_parquet(tmp_path / "a" / "frames.parquet")
    assert (tmp_path / "a" / "blur" / "000000.png").read_bytes() == (tmp_path / "b" / "blur" / "000000.png").read_bytes()
    mid = len(df) // 2
    assert df["illuminance_lux"].iloc[0] == pytest.approx(50.0) and df["illuminance_lux"].iloc[-1] == pytest.approx(50_000.0)
    # the step saturates the frames until auto-exposure has caught up
    assert df["saturated_fraction"].iloc[:mid - 1].max() < 0.05
    assert df["saturated_fraction"].iloc[mid + 1] > 0.5
    assert df["exposure_us"].iloc[-1] * df["gain"].iloc[-1] < df["exposure_us"].iloc[0] * df["gain"].iloc[0] / 10
    stats = json.loads((tmp_path / "a" / "render_stats.json").read_text())
    assert stats["light"]["condition"] == "hdr" and stats["camera"]["model"] == "sensor"


def test_unlit_frames_keep_their_columns(scene, tmp_path):
    from gs2e.render.dataset import render_dataset
    from gs2e.render.settings import RenderSettings

    model, traj = scene
    render_dataset(model, traj, tmp_path / "f", RenderSettings.defaults(fps=30.0, write_depth=False))
    df = pd.read_parquet(tmp_path / "f" / "frames.parquet")
    assert "gain" not in df and "illuminance_lux" not in df


def _events(model, traj, tmp, name, section, light=None):
    from gs2e.events.io import read_h5
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings
    from gs2e.events.simulate import simulate_to_folder

    cfg = event_settings({"preview": False, **section})
    src = RenderedSource(model, traj, cfg, light=light)
    simulate_to_folder(src, cfg, tmp / name, 3)
    ev, attrs = read_h5(tmp / name / "events.h5")
    return ev, src


def test_events_follow_the_light(scene, tmp_path):
    """A light s times the reference is the reference with the dark floor
    log_eps / s (the ideal model sees log(s L + eps) = log s + log(L + eps / s)):
    20x (day) is the run with eps / 20; at night the floor swallows changes."""
    model, traj = scene
    sec = {"model": "ideal", "theta_on": 0.1, "theta_off": 0.1, "max_duration_s": 0.1,
           "sampling": {"mode": "fixed", "fixed_fps": 2000.0}}
    base, _ = _events(model, traj, tmp_path, "base", sec)
    conds = LightSettings.defaults()
    day, _ = _events(model, traj, tmp_path, "day", sec, conds.condition("day"))
    night, _ = _events(model, traj, tmp_path, "night", sec, conds.condition("night"))
    eps20, _ = _events(model, traj, tmp_path, "eps20", {**sec, "log_eps": 1e-3 / 20})
    assert len(base) > 1000 and len(day) > len(base)
    assert len(day) == pytest.approx(len(eps20), rel=0.005)  # float32 rounding apart
    assert len(night) < 0.5 * len(base)  # 1/100 of the light: the floor swallows most changes


def test_flicker_fires_events_at_its_frequency(scene, tmp_path):
    """A still-ish camera under 100 Hz flicker: the ON events' rate peaks at 100 Hz."""
    from gs2e.testing import straight_trajectory

    model, _ = scene
    slow = straight_trajectory(tmp_path, dx=0.003)
    sec = {"model": "ideal", "theta_on": 0.1, "theta_off": 0.1, "max_duration_s": 0.2,
           "sampling": {"mode": "fixed", "fixed_fps": 4000.0}}
    ev, _ = _events(model, slow, tmp_path, "fl", sec, LightSettings.defaults().condition("flicker100"))
    on = ev.t[ev.p == 1]
    h, _ = np.histogram(on, bins=np.arange(on.min(), on.min() + 200_000, 250))
    f = np.fft.rfftfreq(len(h), 250e-6)
    p = np.abs(np.fft.rfft(h - h.mean())) ** 2
    assert f[np.argmax(p * (f > 20))] == pytest.approx(100.0, abs=5.0)  # 5 Hz bins over 0.2 s


def test_colour_pixels_follow_their_own_channel():
    """Each pixel under an RGGB filter sees only its channel: its events are
    those of the ideal model on that channel alone, event for event."""
    from gs2e.common.color import srgb_to_linear
    from gs2e.events.models import IdealModel
    from gs2e.events.sampling import cfa_channels, image_cfa

    H, W, T = 24, 32, 40
    xs = np.arange(W)
    frames = []
    for k in range(T):  # a bar of three colours moving right by 0.6 px per frame
        img = np.full((H, W, 3), 0.15)
        for c, off in enumerate((0, 4, 8)):
            on = np.abs(xs - (4 + off + 0.6 * k)) < 2.5
            img[:, on, c] = 0.9
        frames.append(img)
    ch = cfa_channels("RGGB")
    cfa = np.empty((T, H, W), np.float32)
    for k, f in enumerate(frames):
        image_cfa(f, ch, cfa[k])
    ts = np.arange(T, dtype=np.int64) * 1000

    def run(fr):
        return _all(IdealModel((H, W), theta_on=0.2, theta_off=0.2, seed=1), ts, fr)

    got = run(cfa)
    assert len(got) > 100
    ref_t, ref_x, ref_y, ref_p = [], [], [], []
    for c in range(3):
        lin = np.stack([srgb_to_linear(f[..., c], clip=True) for f in frames]).astype(np.float32)
        ev = run(lin)
        keep = ch[ev.y % 2, ev.x % 2] == c
        ref_t.append(ev.t[keep]), ref_x.append(ev.x[keep]), ref_y.append(ev.y[keep]), ref_p.append(ev.p[keep])
    ref = sorted(zip(np.concatenate(ref_t), np.concatenate(ref_y), np.concatenate(ref_x), np.concatenate(ref_p)))
    mine = sorted(zip(got.t, got.y, got.x, got.p))
    assert mine == ref


def _all(model, ts, frames):
    from gs2e.events.models import Events

    model.start(int(ts[0]), frames[0])
    return Events.concat([model.process_batch(ts[1:], frames[1:]), model.flush()])


def test_colour_sensor_renders_cfa_events_and_eventnerf_reads_them(scene, tmp_path):
    from gs2e.events.sensors import SENSORS, resolve_cfa
    from gs2e.events.settings import event_settings

    assert resolve_cfa(event_settings({"sensor": "color_davis346"})) == "RGGB"
    assert resolve_cfa(event_settings({"sensor": "color_davis346", "cfa": "none"})) is None
    assert SENSORS["color_davis346"].size == (346, 260)
    model, traj = scene
    sec = {"model": "ideal", "theta_on": 0.2, "theta_off": 0.2, "max_duration_s": 0.02, "cfa": "RGGB",
           "sampling": {"mode": "fixed", "fixed_fps": 2000.0}}
    ev, src = _events(model, traj, tmp_path, "col", sec)
    meta = json.loads((tmp_path / "col" / "stats.json").read_text())["metadata"]
    assert len(ev) > 0 and src.cfa_pattern == "RGGB"
    with pytest.raises(ConfigError, match="tile"):
        _events(model, traj, tmp_path, "colt", {**sec, "sampling": {"mode": "tile"}})
    assert meta["cfa"] == "RGGB"  # what the exports read (gs2e.export.source.TrajectorySource.cfa)
    from gs2e.export.source import TrajectorySource

    assert TrajectorySource.cfa.fget(type("S", (), {"events_file": tmp_path / "col" / "events.h5"})()) == "RGGB"


def test_leak_grows_with_the_light_and_keeps_its_bytes_without_it():
    """The noise kernel: leak + leak_light L, thinned at the largest rate; with
    leak_light 0 the same events as before the light existed (same draws)."""
    from gs2e.events.models import IdealModel

    H, W = 64, 64
    lum = np.tile(np.linspace(0.0, 4.0, W, dtype=np.float32), (H, 1))
    frames = np.stack([lum, lum])
    ts = np.array([0, 50_000_000], np.int64)

    def run(**kw):
        return _all(IdealModel((H, W), theta_on=5.0, theta_off=5.0, seed=9, **kw), ts, frames)

    a = run(leak_rate_hz=0.5, lum_max=4.0, leak_light_rate_hz=2.0)
    dark, bright = (a.x < W // 4).sum(), (a.x >= 3 * W // 4).sum()
    # mean L 0.5 vs 3.5 over the quarters: rates 0.5 + 2 L -> 1.5 vs 7.5 Hz
    assert bright / dark == pytest.approx(7.5 / 1.5, rel=0.1)
    assert np.all(a.p == 1)  # leak events are ON
    lo = np.clip(frames, 0, 1)
    b = _all(IdealModel((H, W), theta_on=5.0, theta_off=5.0, seed=9, leak_rate_hz=0.5,
                        shot_noise_rate_hz=0.2), ts, lo)
    c = _all(IdealModel((H, W), theta_on=5.0, theta_off=5.0, seed=9, leak_rate_hz=0.5,
                        shot_noise_rate_hz=0.2, leak_light_rate_hz=0.0, lum_max=1.0), ts, lo)
    assert np.array_equal(b.t, c.t) and np.array_equal(b.x, c.x) and np.array_equal(b.p, c.p)


def test_workflow_plans_runs_under_a_light(tmp_path):
    from gs2e.testing import run_snakemake
    from tests.conftest import REPO, planned_jobs

    proc = run_snakemake("-n", "-p", "--cores", "2", "--directory", str(tmp_path), "--config",
                         f"scenes={REPO / 'config' / 'scenes.tsv'}", f"results_dir={tmp_path / 'out'}",
                         "light={runs: [dim]}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = planned_jobs(proc.stdout)
    # the demo's four trajectories, and each again @dim: rendered, simulated and benchmarked
    assert jobs["render"] == 8 and jobs["events"] == 8 and jobs["windows"] == 8
    assert jobs["bench"] == 2 * 8  # deblur and video on every run
    assert "frames/base_mild@dim" in proc.stdout and "events/mini00_medium@dim" in proc.stdout
    assert proc.stdout.count("--light-json") == 8  # the lit runs' render and events jobs only


def test_colour_sensors_are_known_to_the_config_and_refused_by_sim2real():
    from gs2e.config import COLOUR_SENSORS, load_config
    from gs2e.events.sensors import SENSORS

    assert COLOUR_SENSORS == {n for n, s in SENSORS.items() if s.extra.get("cfa")}
    with pytest.raises(ConfigError, match="colour filter"):
        load_config({"bench": {"sim2real_variants": ["color_davis346"]}})


def test_leak_against_brightness_recovers_a_line_and_refuses_too_little():
    from gs2e.events.stats import leak_against_brightness

    shot = 0.001
    bins = [{"lum_mean": L, "n_pixels": n, "ba_rate_hz": 0.002 + 0.004 * L + shot * 2 * (1 - L)}
            for L, n in ((0.1, 500), (0.3, 800), (0.6, 300), (1.2, 50))]  # a bin above 1: no shot noise there
    bins[-1]["ba_rate_hz"] = 0.002 + 0.004 * 1.2
    fit = leak_against_brightness(bins, shot)
    assert fit["leak_dark_rate_hz"] == pytest.approx(0.002) and fit["leak_light_rate_hz"] == pytest.approx(0.004)
    falling = [dict(b, ba_rate_hz=0.01 - 0.005 * b["lum_mean"]) for b in bins]
    assert leak_against_brightness(falling, 0.0)["leak_light_rate_hz"] == 0.0  # held >= 0
    assert math.isnan(leak_against_brightness(bins[:1], shot)["leak_light_rate_hz"])
    assert math.isnan(leak_against_brightness(bins, float("nan"))["leak_dark_rate_hz"])
