"""Target sensors (events.sensor): camera fitting, frame fitting, the values
a preset sets and their precedence, custom sensor files, and the sensor's
pixel array end to end (frames and rendered)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from gs2e.common.camera import fit_camera
from gs2e.common.errors import ConfigError, InputError
from gs2e.config import load_config
from gs2e.events.sensors import SENSORS, fit_frame, get_sensor, load_sensor_file, resolve_noise
from gs2e.events.settings import EventSettings, event_settings

sys.path.insert(0, str(Path(__file__).parent))


def _events_cfg(**kw) -> EventSettings:
    return event_settings(load_config({"events": kw})["events"])


def _project(K, pts):
    uv = (np.asarray(K) @ pts.T).T
    return uv[:, :2] / uv[:, 2:]


@pytest.mark.parametrize("size,sensor", [((319, 239), (346, 260)), ((640, 480), (1280, 720)),
                                         ((480, 640), (346, 260)), ((706, 529), (640, 480)),
                                         ((1280, 720), (640, 480))])
@pytest.mark.parametrize("fit", ["cover", "contain"])
def test_fitted_camera_is_a_centred_uniform_scaling(size, sensor, fit):
    (W, H), (Ws, Hs) = size, sensor
    K = np.array([[0.9 * W, 0, 0.52 * W], [0, 0.9 * W, 0.47 * H], [0, 0, 1.0]])  # off-centre
    Ks = fit_camera(K, W, H, Ws, Hs, fit)
    s = Ks[0, 0] / K[0, 0]
    assert Ks[1, 1] / K[1, 1] == pytest.approx(s)  # square pixels stay square
    pts = np.random.default_rng(0).normal(size=(50, 3)) + [0, 0, 4]
    # every point lands where the image-plane scaling about the centres puts it
    want = s * _project(K, pts) + [(Ws - s * W) / 2, (Hs - s * H) / 2]
    assert np.allclose(_project(Ks, pts), want)
    # cover: the sensor sees only inside the scene image; contain: all of it
    corners = np.array([[0, 0], [Ws, Hs]], float)
    back = (corners - [(Ws - s * W) / 2, (Hs - s * H) / 2]) / s
    if fit == "cover":
        assert back.min() >= -1e-9 and back[1, 0] <= W + 1e-9 and back[1, 1] <= H + 1e-9
        assert np.isclose(back[0], 0).any()  # tight on one axis
    else:
        assert back[0, 0] <= 1e-9 and back[0, 1] <= 1e-9 and back[1, 0] >= W - 1e-9
        assert back[1, 1] >= H - 1e-9


def test_fitted_frames_follow_the_same_geometry():
    # a linear ramp maps to the ramp at the mapped coordinates (interior pixels)
    H, W, Ws, Hs = 120, 200, 90, 60
    y, x = np.mgrid[0:H, 0:W] + 0.5
    ramp = (0.001 * x + 0.002 * y).astype(np.float32)
    for fit in ("cover", "contain"):
        out = fit_frame(ramp, Ws, Hs, fit)
        assert out.shape == (Hs, Ws) and out.dtype == np.float32
        s = min(Ws / W, Hs / H) if fit == "contain" else max(Ws / W, Hs / H)
        v, u = np.mgrid[0:Hs, 0:Ws] + 0.5
        xs, ys = (u - (Ws - s * W) / 2) / s, (v - (Hs - s * H) / 2) / s
        inside = (xs > 3) & (xs < W - 3) & (ys > 3) & (ys < H - 3)
        assert inside.sum() > 0.5 * Ws * Hs * (0.6 if fit == "contain" else 0.9)
        assert np.abs(out - (0.001 * xs + 0.002 * ys))[inside].max() < 2e-4
        if fit == "contain":  # borders outside the scene image are black (no signal)
            assert np.all(out[(xs < -1) | (xs > W + 1) | (ys < -1) | (ys > H + 1)] == 0)
    # hard cases: a black frame stays black; a strong shrink of fine texture keeps
    # the mean (area filter, no aliasing); an upscaled constant stays constant
    assert not fit_frame(np.zeros((720, 1280), np.float32), 346, 260).any()
    checker = ((np.indices((720, 1280)).sum(0) % 2) * 0.8 + 0.1).astype(np.float32)
    small = fit_frame(checker, 346, 260)
    assert abs(small.mean() - 0.5) < 0.01 and small.std() < 0.05
    assert np.allclose(fit_frame(np.full((24, 32), 0.3, np.float32), 1280, 720, "cover"), 0.3)


def test_sensor_values_precedence_and_sources():
    none, src = resolve_noise(_events_cfg(), 1.0)
    assert none == {"theta_mismatch_sigma": 0.0, "refractory_us": 0.0, "leak_rate_hz": 0.0,
                    "leak_light_rate_hz": 0.0, "shot_noise_rate_hz": 0.0, "shot_noise_on_fraction": 0.5}
    assert set(src.values()) == {"default (no sensor)"}
    vals, src = resolve_noise(_events_cfg(sensor="dvxplorer", refractory_us=20.0), 0.4)
    dvx = SENSORS["dvxplorer"]
    assert vals["refractory_us"] == 20.0 and src["refractory_us"] == "config"  # config wins
    assert vals["shot_noise_rate_hz"] == dvx.shot_noise_rate_hz.value
    assert "measured" in src["shot_noise_rate_hz"]
    # the mismatch is relative: sigma follows the threshold it perturbs
    assert vals["theta_mismatch_sigma"] == pytest.approx(dvx.theta_mismatch_rel.value * 0.4)
    assert "assumed" in src["theta_mismatch_sigma"]


def test_custom_sensor_file(tmp_path):
    f = tmp_path / "cam.yaml"
    f.write_text("name: mycam\nwidth: 320\nheight: 240\nshot_noise_rate_hz: {value: 0.7, "
                 "source: measured from rec.aedat4}\nrefractory_us: 250\n")
    s = load_sensor_file(f)
    assert s.size == (320, 240) and s.shot_noise_rate_hz.source == "measured from rec.aedat4"
    assert s.refractory_us.value == 250 and s.leak_rate_hz.value == 0
    cfg = _events_cfg(sensor="custom", sensor_file=str(f))
    assert get_sensor(cfg).name == "mycam"
    for text, msg in [("width: 320\n", "lacks 'height'"),
                      ("width: 320\nheight: 240\nleak_rate_hz: -1\n", "'leak_rate_hz' must be"),
                      ("width: 32.5\nheight: 240\n", "positive integers"),
                      ("- 1\n", "YAML mapping")]:
        f.write_text(text)
        with pytest.raises(InputError, match=msg) as e:
            load_sensor_file(f)
        assert str(f) in str(e.value)
    with pytest.raises(ConfigError, match="needs events.sensor_file"):
        _events_cfg(sensor="custom")
    with pytest.raises(ConfigError, match="does not exist"):
        _events_cfg(sensor="custom", sensor_file=str(tmp_path / "missing.yaml"))
    with pytest.raises(ConfigError, match="set events.sensor: custom"):
        _events_cfg(sensor="davis346", sensor_file=str(f))


def test_frames_simulated_at_the_sensor_size(tmp_path):
    from gs2e.cli import main

    rng = np.random.default_rng(1)
    base = rng.uniform(0.1, 0.9, (48, 64)).astype(np.float32)
    frames = np.stack([np.roll(base, i, axis=1) for i in range(6)])
    np.save(tmp_path / "f.npy", frames)
    out = tmp_path / "o"
    assert main(["events", str(tmp_path / "f.npy"), "--fps", "1000", "-o", str(out),
                 "--set", "sensor=davis346", "--set", "model=ideal", "--set", "preview=false"]) == 0
    import hdf5plugin  # noqa: F401  (blosc, the default compression)

    with h5py.File(out / "events.h5") as h:
        assert (h.attrs["width"], h.attrs["height"]) == (346, 260)
        x, y = h["events/x"][:], h["events/y"][:]
    assert len(x) > 1000 and x.max() < 346 and y.max() < 260 and x.max() > 300
    meta = json.loads((out / "stats.json").read_text())["metadata"]
    assert meta["camera"]["sensor"] == "davis346" and meta["camera"]["input_shape"] == [48, 64]
    assert meta["noise"]["refractory_us"] == 100.0


@pytest.mark.parametrize("size", [(128, 80), (96, 90)])  # wider (cover crops rows), taller
def test_rendered_at_the_sensor_matches_the_scene_camera(tmp_path, size):
    """The sensor camera renders what the scene camera sees, scaled and
    cropped as fit_frame does: both paths share one geometry. (Sensors larger
    than the 64x48 scene camera: a smaller one would alias the 0.6 px Gaussians.)"""
    from gs2e.testing import plane_model, straight_trajectory

    from gs2e.events.rendered import RenderedSource
    from gs2e.events.sampling import image_luminance

    w, h = size
    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 0.2)
    f = tmp_path / "s.yaml"
    f.write_text(f"width: {w}\nheight: {h}\n")
    full = RenderedSource(model, traj, _events_cfg(model="ideal"))
    sens = RenderedSource(model, traj, _events_cfg(model="ideal", sensor="custom", sensor_file=str(f)))
    assert full.shape == (48, 64) and sens.shape == (h, w)
    assert np.allclose(sens.K, fit_camera(full.K, 64, 48, w, h, "cover"))
    assert sens.camera["trajectory_camera"]["width"] == 64
    t = int(full.t0_us)
    a, b = np.empty((48, 64), np.float32), np.empty((h, w), np.float32)
    image_luminance(full.renderer.render(full.pose_at(t)), a)
    image_luminance(sens.renderer.render(sens.pose_at(t)), b)

    def err(dy, dx):
        return np.abs(fit_frame(np.roll(a, (dy, dx), axis=(0, 1)), w, h) - b)[2:-2, 2:-2].mean()

    # the fitted frame lines up with the sensor render better than any one-pixel slip
    e0 = err(0, 0)
    assert e0 < 0.1 * b.std()
    assert min(err(dy, dx) for dy, dx in [(1, 0), (-1, 0), (0, 1), (0, -1)]) > 1.4 * e0


def test_training_resolution_follows_the_sensor_ingest_does_not(tmp_path):
    """Ingest (and so SfM) keeps the photos' resolution whatever the sensor;
    training with splat.max_side=auto shrinks the views to the smallest size
    that still covers the sensor's array (a DAVIS346 dataset does not train at
    full size), portrait views by the same angular resolution; no target keeps
    the resolution; a number set by the user wins; never enlarges."""
    import cv2

    from gs2e.cli import main
    from gs2e.io.images import cover_max_side
    from gs2e.io.scene import Camera, Frame, Scene, read_scene
    from gs2e.splat.views import train_sizes

    assert cover_max_side(640, 480, (346, 260)) == 347  # 347x260 covers 346x260
    assert cover_max_side(480, 640, (346, 260)) == 462  # portrait views: width binds
    assert cover_max_side(320, 240, (346, 260)) is None  # never enlarges
    assert cover_max_side(640, 480, None) is None
    src = tmp_path / "src"
    src.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(src / f"{i}.png"), rng.integers(0, 255, (480, 640, 3), dtype=np.uint8))
    assert main(["ingest", "--layout", "folder", "--src", str(src), "--out", str(tmp_path / "ing")]) == 0
    assert (read_scene(tmp_path / "ing").width, read_scene(tmp_path / "ing").height) == (640, 480)
    with pytest.raises(SystemExit):  # ingest takes no sensor any more
        main(["ingest", "--layout", "folder", "--src", str(src), "--out", str(tmp_path / "x"),
              "--target-size", "346x260"])

    land, port = Camera(500.0, 500.0, 320.0, 240.0), Camera(500.0, 500.0, 240.0, 320.0)
    zoom = Camera(1000.0, 1000.0, 640.0, 480.0)  # twice the angular resolution
    wide = Camera(250.0, 250.0, 320.0, 240.0)  # half: an outlier that must not set the reference
    eye = np.eye(4)
    scene = Scene(640, 480, [Frame("w", wide, eye), Frame("a", land, eye), Frame("b", port, eye),
                             Frame("c", land, eye), Frame("d", zoom, eye)],
                  extra={"frame_sizes": [[640, 480], [640, 480], [480, 640], [640, 480], [1280, 960]]})
    native = [(640, 480), (640, 480), (480, 640), (640, 480), (1280, 960)]
    assert train_sizes(scene, "auto", (346, 260)) == \
        ((347, 260), [(640, 480), (347, 260), (260, 347), (347, 260), (347, 260)])
    assert train_sizes(scene, "auto", None) == ((640, 480), native)
    assert train_sizes(scene, None, (346, 260)) == ((640, 480), native)
    assert train_sizes(scene, 200, (346, 260)) == \
        ((200, 150), [(400, 300), (200, 150), (150, 200), (200, 150), (200, 150)])
    assert train_sizes(scene, "auto", (1280, 720)) == ((640, 480), native)
    with pytest.raises(SystemExit):
        main(["train", "--scene", str(tmp_path / "ing"), "--out", str(tmp_path / "t"),
              "--target-size", "346by260"])


def test_sampling_signal_is_the_models_own():
    """The sampling bound applies to the signal each model integrates: the
    ideal model's log(L + log_eps), DVS-Voltmeter's log(L + k2 / scale)."""
    from gs2e.events.rendered import sampling_log_eps

    assert sampling_log_eps(_events_cfg(model="ideal", log_eps=0.01)) == 0.01
    assert sampling_log_eps(_events_cfg(model="voltmeter")) == pytest.approx(20.0 / 255.0)
    assert sampling_log_eps(_events_cfg(model="voltmeter", k2=51.0)) == pytest.approx(0.2)
    assert sampling_log_eps(_events_cfg(model="voltmeter", preset="gs2e_paper")) == pytest.approx(1e-3)


def test_frames_and_events_share_the_sensor_camera(tmp_path):
    """gs2e render --sensor-size renders the dataset frames through the camera
    the event stage uses for the same sensor: same array, same intrinsics."""
    import cv2
    import pandas as pd
    from gs2e.testing import plane_model, straight_trajectory

    from gs2e.cli import main
    from gs2e.events.rendered import RenderedSource

    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 0.2)
    f = tmp_path / "s.yaml"
    f.write_text("width: 96\nheight: 90\n")
    out = tmp_path / "frames"
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out", str(out),
                 "--sensor-size", "96x90", "--config-json",
                 '{"fps": 50, "exposure_us": 2000, "write_depth": false, "scale": 0.5}']) == 0
    fr = pd.read_parquet(out / "frames.parquet")
    assert set(fr["width"]) == {96} and set(fr["height"]) == {90}  # scale does not apply
    ev = RenderedSource(model, traj, _events_cfg(sensor="custom", sensor_file=str(f)))
    K = np.array([[fr["fx"][0], 0, fr["cx"][0]], [0, fr["fy"][0], fr["cy"][0]], [0, 0, 1]])
    assert np.allclose(K, ev.K)
    assert cv2.imread(str(sorted((out / "rgb").iterdir())[0])).shape == (90, 96, 3)
