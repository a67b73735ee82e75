"""The sensor around the pixel model (gs2e.events.readout): photoreceptor
low-pass, hot pixels and a readout of finite throughput, each on its hard
case, and the chain with all three off handing the model's events on
untouched."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gs2e.common.errors import InputError
from gs2e.events.models import Events, make_model
from gs2e.events.readout import (HOT_BLOCK_US, Photoreceptor, Readout, SensorChain, hot_pixel_events,
                                 hot_pixels, lowpass_step, resolve_readout)
from gs2e.events.settings import event_settings

H, W = 32, 48


def _frames(n=201, dt_us=500, lum=0.3, amp=0.2, freq_hz=20.0):
    ts = np.arange(n, dtype=np.int64) * dt_us
    x = np.arange(W)[None, :]
    fr = np.stack([np.broadcast_to(lum + amp * np.sin(0.4 * x + 2 * np.pi * freq_hz * t * 1e-6), (H, W))
                   for t in ts]).astype(np.float32)
    return ts, fr


def _sim(extra, ts, fr, seed=3, batch=None):
    s = event_settings({"model": "ideal", "theta_on": 0.2, "theta_off": 0.2, **extra})
    m, _ = make_model(s, fr.shape[1:], seed)
    chain = SensorChain(m, resolve_readout(s)[0], seed)
    if batch is None:
        return chain.simulate(ts, fr)
    chain.start(int(ts[0]), fr[0])
    out = [chain.process_batch(ts[i:i + batch], fr[i:i + batch]) for i in range(1, len(ts), batch)]
    return Events.concat(out + [chain.flush()])


def _same(a: Events, b: Events) -> bool:
    return all(np.array_equal(getattr(a, k), getattr(b, k)) for k in "txyp")


def test_chain_checks_before_it_runs():
    ts, fr = _frames(n=5)
    s = {"model": "ideal", "hot_pixel_fraction": 0.1, "hot_pixel_rate_hz": 5.0}
    m, _ = make_model(event_settings(s), (H, W), 0)
    chain = SensorChain(m, resolve_readout(event_settings(s))[0], 0)
    with pytest.raises(InputError, match="start"):
        chain.process_batch(ts[1:], fr[1:])
    chain.start(int(ts[0]), fr[0])
    with pytest.raises(InputError, match="integer"):
        chain.process_batch(ts[1:] + 0.5, fr[1:])
    assert len(chain.process_batch(ts[:0], fr[:0])) == 0


def test_chain_off_is_the_model():
    ts, fr = _frames()
    m, _ = make_model(event_settings({"model": "ideal", "theta_on": 0.2, "theta_off": 0.2}), (H, W), 3)
    bare = m.simulate(ts, fr)
    assert len(bare) > 1000
    assert _same(_sim({}, ts, fr), bare)
    r, src = resolve_readout(event_settings({}))
    assert not r.any_on and src["readout_rate_meps"].startswith("default")


# ---------------------------------------------------------------- photoreceptor
def _ode_reference(x0, x1, y0, dt_us, fc_hz, n=200000):
    """dy/dt = 2 pi fc (x(t) - y), x linear from x0 to x1, by RK4 in small steps."""
    h = dt_us * 1e-6 / n
    y = y0
    k = 2 * math.pi * fc_hz
    for i in range(n):
        t = i * h
        f = lambda tt, yy: k * (x0 + (x1 - x0) * tt / (dt_us * 1e-6) - yy)  # noqa: E731
        a = f(t, y)
        b = f(t + h / 2, y + h / 2 * a)
        c = f(t + h / 2, y + h / 2 * b)
        d = f(t + h, y + h * c)
        y += h / 6 * (a + 2 * b + 2 * c + d)
    return y


@pytest.mark.parametrize("x0,x1,y0,dt_us", [(0.1, 0.8, 0.3, 2000.0), (0.9, 0.05, 0.5, 50.0),
                                            (0.2, 0.2, 0.7, 10000.0), (0.0, 1e-6, 0.0, 1e-3)])
def test_lowpass_step_is_exact_for_a_linear_input(x0, x1, y0, dt_us):
    cutoff, dark = 300.0, 0.1
    fc = cutoff * (0.5 * (x0 + x1) + dark) / (1 + dark)
    got = float(lowpass_step(np.array(y0), np.array(x0), np.array(x1), dt_us, cutoff, dark))
    assert got == pytest.approx(_ode_reference(x0, x1, y0, dt_us, fc), abs=1e-9)


def test_lowpass_dark_pixels_lag():
    """A step from dark: the darker the scene, the later the filtered output
    reaches half the step (the cutoff falls with the light)."""
    ts = np.arange(0, 20001, 100, dtype=np.int64)
    half_times = []
    for level in (0.01, 0.1, 1.0):
        fr = np.full((len(ts), 1, 1), level * 0.5, np.float32)
        fr[ts >= 1000] = level
        pr = Photoreceptor(200.0, 0.05)
        pr.start(int(ts[0]), fr[0])
        y = pr.filter(ts[1:], fr[1:])[:, 0, 0]
        half_times.append(int(ts[1:][np.argmax(y >= 0.75 * level)]))
    assert half_times[0] > half_times[1] > half_times[2]
    # at full white the time constant is 1 / (2 pi 200 Hz) = 0.8 ms: log(2) tau to half
    assert half_times[2] - 1000 == pytest.approx(math.log(2) / (2 * math.pi * 200) * 1e6, abs=150)


def test_lowpass_flicker_is_attenuated():
    """A pixel flickering far above the cutoff barely fires with the low-pass."""
    ts, fr = _frames(n=401, dt_us=100, amp=0.1, freq_hz=2000.0)
    plain = _sim({}, ts, fr)
    filtered = _sim({"photoreceptor_cutoff_hz": 50.0, "photoreceptor_dark_fraction": 0.1}, ts, fr)
    assert len(filtered) < 0.05 * len(plain)


def test_lowpass_tiles_match_frames():
    """The tile path of the low-pass filters each tile as the frame path does."""
    from gs2e.events.models import TILE, TileBatch

    ts, fr = _frames(n=5)
    a = Photoreceptor(300.0, 0.1)
    a.start(int(ts[0]), fr[0])
    want = a.filter(ts[1:], fr[1:])
    b = Photoreceptor(300.0, 0.1)
    b.start(int(ts[0]), fr[0])
    batch = TileBatch.from_frames(ts, fr[1:], 1)
    got = b.filter_tiles(batch, TILE, W)
    n_tx = -(-W // TILE)
    for s, tid in enumerate(batch.tiles):
        y0, x0 = (tid // n_tx) * TILE, (tid % n_tx) * TILE
        for j, k in enumerate(range(batch.offsets[s], batch.offsets[s + 1])):
            h, w = min(TILE, H - y0), min(TILE, W - x0)
            np.testing.assert_allclose(got.lum[k, :h, :w], want[j, y0:y0 + h, x0:x0 + w], rtol=1e-6)


# ---------------------------------------------------------------- hot pixels
def test_hot_pixels_rate_count_and_batching():
    pix = hot_pixels((H, W), 0.02, seed=5)
    assert len(pix) == round(0.02 * H * W) and len(np.unique(pix)) == len(pix)
    rate, t1 = 40.0, 3 * HOT_BLOCK_US + 12345
    ev = hot_pixel_events(pix, W, rate, 0.8, 0, t1, seed=5)
    expected = len(pix) * rate * t1 * 1e-6
    assert abs(len(ev) - expected) < 4 * math.sqrt(expected)
    assert np.all(np.diff(ev.t) >= 0)
    assert set(np.unique(ev.y.astype(int) * W + ev.x)) <= set(pix.tolist())
    assert abs(ev.p.mean() - 0.8) < 4 * math.sqrt(0.16 / len(ev))
    # cut anywhere: the same events
    cuts = [0, 777, HOT_BLOCK_US, HOT_BLOCK_US + 1, 2 * HOT_BLOCK_US + 5000, t1]
    parts = Events.concat([hot_pixel_events(pix, W, rate, 0.8, a, b, seed=5) for a, b in zip(cuts, cuts[1:])])
    assert _same(parts, ev)


def test_hot_pixels_in_the_chain_do_not_depend_on_batching():
    ts, fr = _frames(n=121)
    extra = {"hot_pixel_fraction": 0.05, "hot_pixel_rate_hz": 300.0}
    a, b = _sim(extra, ts, fr, batch=7), _sim(extra, ts, fr, batch=50)
    assert _same(a, b)
    assert len(a) > len(_sim({}, ts, fr))


# ---------------------------------------------------------------- readout
def test_readout_drops_the_excess_of_a_burst():
    """1000 events at one instant into a queue of 63: 64 leave (one served at
    once, 63 waiting), one per service time, after the latency."""
    n = 1000
    ev = Events(np.full(n, 5000, np.int64), np.arange(n, dtype=np.uint16) % W,
                np.zeros(n, np.uint16), np.ones(n, np.uint8))
    r = Readout(rate_meps=2.0, latency_us=30.0, jitter_us=0.0, queue_events=63, seed=0)
    out = Events.concat([r.process(ev, 5001), r.flush()])
    assert len(out) == 64 and r.dropped == n - 64
    want = np.floor(5000 + 30 + 0.5 * np.arange(1, 65)).astype(np.int64)
    np.testing.assert_array_equal(out.t, want)


def test_readout_keeps_a_stream_it_can_carry():
    rng = np.random.default_rng(0)
    n = 20000
    t = np.sort(rng.integers(0, 1_000_000, n))  # 0.02 Mev/s into a 1 Mev/s readout
    ev = Events(t, rng.integers(0, W, n).astype(np.uint16), rng.integers(0, H, n).astype(np.uint16),
                rng.integers(0, 2, n).astype(np.uint8))
    r = Readout(1.0, 10.0, 4.0, 16, seed=1)
    out = Events.concat([r.process(ev, None)])
    assert len(out) == n and r.dropped == 0
    assert np.all(np.diff(out.t) >= 0)
    # jitter within +-4 us around departure + 10 us; never before the pixel's time
    lag = np.sort(out.t) - np.sort(t)
    assert lag.min() >= 0 and lag.max() <= 10 + 4 + 20  # queueing adds at most a few service times


def test_readout_streaming_equals_one_pass():
    ts, fr = _frames(n=161)
    extra = {"readout_rate_meps": 0.5, "readout_latency_us": 50.0, "readout_jitter_us": 20.0,
             "readout_queue_events": 8}
    a, b = _sim(extra, ts, fr, batch=3), _sim(extra, ts, fr, batch=200)
    assert _same(a, b)
    assert np.all(np.diff(a.t) >= 0)
    plain = _sim({}, ts, fr)
    assert 0 < len(a) < len(plain)  # a 0.5 Mev/s readout cannot carry these bursts


def test_readout_from_a_sensor_file(tmp_path):
    from gs2e.events.sensors import get_sensor

    f = tmp_path / "s.yaml"
    f.write_text("width: 48\nheight: 32\nhot_pixel_fraction: 0.01\nhot_pixel_rate_hz: {value: 5, source: me}\n"
                 "readout_rate_meps: 2\n")
    s = {"sensor": "custom", "sensor_file": str(f)}
    r, src = resolve_readout(event_settings(s))
    assert r.hot_pixel_fraction == 0.01 and r.hot_pixel_rate_hz == 5 and r.readout_rate_meps == 2
    assert "me" in src["hot_pixel_rate_hz"] and src["readout_latency_us"].startswith("default")
    assert get_sensor(event_settings(s)).to_dict()["readout"]["hot_pixel_fraction"]["value"] == 0.01
    # config wins over the sensor
    r2, src2 = resolve_readout(event_settings({**s, "hot_pixel_rate_hz": 9.0}))
    assert r2.hot_pixel_rate_hz == 9.0 and src2["hot_pixel_rate_hz"] == "config"
    f.write_text("width: 48\nheight: 32\nhot_pixel_fraction: 3\n")
    with pytest.raises(InputError, match="hot_pixel_fraction"):
        get_sensor(event_settings(s))


def test_event_stage_records_the_readout(tmp_path):
    """gs2e's event stage runs the chain: hot pixels in a black scene (a valid
    result: only them), the sources in events.h5's metadata."""
    import json

    from gs2e.events.io import read_h5
    from gs2e.events.simulate import simulate_to_folder

    ts = np.arange(0, 200001, 10000, dtype=np.int64)
    frames = [(int(t), np.zeros((H, W), np.float32)) for t in ts]
    settings = {"model": "ideal", "theta_on": 0.2, "theta_off": 0.2, "hot_pixel_fraction": 0.01,
                "hot_pixel_rate_hz": 100.0, "readout_rate_meps": 1.0, "readout_latency_us": 5.0,
                "preview": False}
    stats = simulate_to_folder(frames, event_settings(settings), tmp_path / "ev", seed=2)
    ev, attrs = read_h5(tmp_path / "ev" / "events.h5")
    hot = set(hot_pixels((H, W), 0.01, 2).tolist())
    assert len(ev) == stats["n_events"] > 0
    assert set(np.unique(ev.y.astype(int) * W + ev.x)) <= hot
    meta = json.loads(attrs["metadata"]) if isinstance(attrs["metadata"], (str, bytes)) else attrs["metadata"]
    assert meta["readout"]["sources"]["hot_pixel_fraction"] == "config"
    assert meta["readout"]["values"]["readout_rate_meps"] == 1.0
