"""Ideal (ESIM-style) model: exactness on log-linear ramps, refractory, edge cases."""

import numpy as np
import pytest

from gs2e.common.errors import InputError
from gs2e.config import load_section
from gs2e.events.models import Events, IdealModel, make_model
from gs2e.events.settings import event_settings


def _ramp(rates_per_s, n_frames, dt_us, start, eps, t0_us=0):
    """Frames whose log(L + eps) is exactly linear in time, per pixel."""
    ts = t0_us + dt_us * np.arange(n_frames, dtype=np.int64)
    g0 = np.log(start + eps)
    frames = np.stack([np.exp(g0 + rates_per_s * (t - t0_us) * 1e-6) - eps for t in ts])
    return ts, frames


@pytest.mark.parametrize("t0_us", [0, (1 << 24) + 12345, (1 << 40) + 3])
def test_exact_on_log_linear_ramps(t0_us):
    H, W = 6, 7
    rates = np.linspace(-9.0, 9.0, H * W).reshape(H, W)  # log units per second
    rates[rates == 0] = 0.0
    eps, th = 1e-3, 0.07
    ts, fr = _ramp(rates, 41, 2500, 0.05, eps, t0_us)  # 0.1 s, ends below 1.0
    assert fr.max() <= 1.0 and fr.min() >= 0.0
    m = IdealModel((H, W), theta_on=th, theta_off=th, log_eps=eps)
    ev = Events.concat([m.process_batch(ts[:17], fr[:17]), m.process_batch(ts[17:], fr[17:]),
                        m.flush()])
    assert np.all(np.diff(ev.t) >= 0)
    T = (ts[-1] - ts[0]) * 1e-6
    n_expected = 0
    for y in range(H):
        for x in range(W):
            r = rates[y, x]
            sel = (ev.y == y) & (ev.x == x)
            k = np.arange(1, int(np.floor(abs(r) * T / th + 1e-9)) + 1)
            t_true = t0_us + k * th / abs(r) * 1e6 if r != 0 else np.empty(0)
            assert sel.sum() == len(k), (y, x, r)
            # exact up to the rounding to integer microseconds
            assert np.all(np.abs(ev.t[sel] - t_true) <= 0.5 + 1e-6)
            assert np.all(ev.p[sel] == (1 if r > 0 else 0))
            n_expected += len(k)
    assert len(ev) == n_expected


def test_refractory_drops_but_reference_advances():
    H, W = 1, 2
    rates = np.array([[19.7, -19.7]])
    eps, th = 1e-3, 0.1  # a crossing every 5076 us, 19 in 0.1 s
    ts, fr = _ramp(rates, 21, 5000, 0.1, eps)
    free = IdealModel((H, W), theta_on=th, theta_off=th, log_eps=eps).simulate(ts, fr)
    m = IdealModel((H, W), theta_on=th, theta_off=th, log_eps=eps, refractory_us=12000)
    ref = m.simulate(ts, fr)
    assert len(free) == 38
    for x in (0, 1):
        t = ref.t[ref.x == x]
        assert np.all(np.diff(t) >= 12000)
        # kept: every 3rd crossing (15228 us apart); the reference still advanced
        assert len(t) == 7
        assert np.all(np.isin(t, free.t[free.x == x]))
    assert np.allclose(m.ref_log, np.log(fr[-1] + eps), atol=th)


def test_black_saturated_constant_and_bad_input():
    H, W = 5, 6
    ts = np.arange(0, 10_001, 1000)
    for val in (0.0, 1.0, 0.5):
        m = IdealModel((H, W), theta_on=0.2, theta_off=0.2)
        assert len(m.simulate(ts, np.full((len(ts), H, W), val))) == 0
    m = IdealModel((H, W))
    # black -> white in one step: many ON events, all inside the interval
    ev = m.simulate([0, 1000], np.stack([np.zeros((H, W)), np.ones((H, W))]))
    assert len(ev) == H * W * int(np.floor(np.log(1.001 / 0.001) / 1.0 + 1e-12))
    assert ev.t.min() >= 0 and ev.t.max() <= 1000
    with pytest.raises(InputError, match="NaN"):
        m.process(2000, np.full((H, W), np.inf))
    with pytest.raises(InputError, match="increase"):
        m.simulate([3000, 3000], np.zeros((2, H, W)))


def test_make_model_theta_sampling_and_mismatch():
    cfg = load_section("events", text='{"model": "ideal", "theta_sampling": "uniform", '
                                      '"theta_mismatch_sigma": 0.03, "theta_range": [0.2, 0.5]}')
    m1, info1 = make_model(event_settings(cfg), (50, 60), seed=4)
    m2, info2 = make_model(event_settings(cfg), (50, 60), seed=4)
    m3, info3 = make_model(event_settings(cfg), (50, 60), seed=5)
    assert 0.2 <= info1["theta_on_nominal"] <= 0.5
    assert info1["theta_on_nominal"] == info1["theta_off_nominal"]
    assert info1 == info2 and info1 != info3
    assert np.array_equal(m1.th_on, m2.th_on)
    assert (m1.th_on > 0).all()
    assert abs(m1.th_on.std() - 0.03) < 0.005
    assert abs(m1.th_on.mean() - info1["theta_on_nominal"]) < 0.003
    # large sigma: still positive (truncated at 5 % of theta)
    cfg2 = dict(cfg, theta_mismatch_sigma=1.0, theta_sampling="fixed", theta_on=0.2)
    m4, _ = make_model(event_settings(cfg2), (50, 60), seed=1)
    assert m4.th_on.min() >= 0.01 - 1e-12


def test_noise_follows_luminance_per_interval_on_uneven_clocks_and_partial_tiles():
    """Noise drawn by thinning per tile and time block is the Poisson process of a
    draw per pixel and interval: counts per luminance phase, over the pixels of
    partial tiles, ON fraction and times inside their intervals, whatever the
    batching."""
    H, W = 37, 45  # partial tiles on both edges
    rng = np.random.default_rng(3)
    ts = np.concatenate([[0], np.cumsum(rng.integers(50, 4000, 1500))]).astype(np.int64)
    bright = (ts // 400_000) % 2 == 1  # phases of 0.4 s: dark (L = 0.1) then bright (0.9)
    lum = np.where(bright, 0.9, 0.1).astype(np.float32)
    fr = np.repeat(lum[:, None, None], H * W, 1).reshape(len(ts), H, W)
    shot, leak, on_frac = 40.0, 5.0, 0.3
    kw = dict(theta_on=50.0, theta_off=50.0, shot_noise_rate_hz=shot, leak_rate_hz=leak,
              shot_noise_on_fraction=on_frac, seed=11)
    ev = IdealModel((H, W), **kw).simulate(ts, fr)
    # expected per pixel: sum over intervals of (leak + 2 shot (1 - mean L)) dt
    mean_l = 0.5 * (lum[:-1] + lum[1:])
    dt_s = np.diff(ts) * 1e-6
    rate = leak + 2.0 * shot * (1.0 - mean_l)
    expect = float((rate * dt_s).sum()) * H * W
    assert abs(len(ev) - expect) < 5 * np.sqrt(expect), (len(ev), expect)
    # per interval phase: the dark intervals have 1.8 / 0.2 the shot rate of the bright ones
    iv = np.searchsorted(ts, ev.t, side="left") - 1
    iv = np.clip(iv, 0, len(dt_s) - 1)
    for phase in (mean_l < 0.5, mean_l > 0.5):
        e = float((rate * dt_s)[phase].sum()) * H * W
        got = int(phase[iv].sum())
        assert abs(got - e) < 5 * np.sqrt(e), (got, e)
    # uniform over pixels, partial tiles included (the last row / column of tiles)
    n = np.bincount(ev.y.astype(np.int64) * W + ev.x, minlength=H * W).reshape(H, W)
    per_px = expect / (H * W)
    edge = n[32:, :].mean(), n[:, 32:].mean()
    for m_ in (n[:32, :32].mean(), *edge):
        assert abs(m_ - per_px) < 0.06 * per_px, (m_, per_px)
    on_expected = float((leak + 2 * shot * (1 - mean_l) * on_frac) @ dt_s / (rate @ dt_s))
    assert abs(ev.p.mean() - on_expected) < 5 * np.sqrt(0.25 / len(ev))
    assert ev.t.min() >= ts[0] and ev.t.max() <= ts[-1] and np.all(np.diff(ev.t) >= 0)
    # batching changes nothing
    m = IdealModel((H, W), **kw)
    parts = [m.process_batch(ts[i:i + 97], fr[i:i + 97]) for i in range(0, len(ts), 97)]
    ev2 = Events.concat(parts + [m.flush()])
    for f in ("t", "x", "y", "p"):
        assert np.array_equal(getattr(ev, f), getattr(ev2, f))


def test_poisson_draw_of_any_mean():
    from numba import njit

    from gs2e.events import _kernels as K

    @njit
    def draws(lam, n):
        st = K.stream_state(5, 0, 0, K.SALT_NOISE)
        out = np.empty(n, np.int64)
        for i in range(n):
            st, out[i] = K._poisson(st, lam)
        return out

    for lam in (0.0, 0.3, 40.0, 2500.0):  # 2500: five draws of 500 (exp(-2500) underflows)
        ks = draws(lam, 4000)
        assert abs(ks.mean() - lam) < 5 * np.sqrt(max(lam, 1e-9) / len(ks)) + 1e-12
        assert abs(ks.var() - lam) < 0.15 * lam + 1e-12


def test_noise_block_depends_on_the_rates_only():
    from gs2e.events._kernels import noise_block_us

    assert noise_block_us(0.0, 0.0, 16) == 1 << 26
    b = noise_block_us(0.01, 0.001, 16)  # the sensor presets: ~8 candidates per tile and block
    assert b & (b - 1) == 0 and 4 <= (0.012 * 256 * b * 1e-6) <= 16
    assert noise_block_us(1e9, 0.0, 16) == 1


def test_noise_off_by_default_and_calibrated_rates():
    H, W, T = 40, 50, 2_000_000
    ts = np.arange(0, T + 1, 20_000)
    fr = np.full((len(ts), H, W), 0.5, np.float32)
    assert len(IdealModel((H, W)).simulate(ts, fr)) == 0
    m = IdealModel((H, W), shot_noise_rate_hz=0.56, shot_noise_on_fraction=0.54,
                   leak_rate_hz=0.2, seed=2)
    ev = m.simulate(ts, fr)
    # luminance 0.5: shot rate x 2 (1 - 0.5) = nominal; leak events are ON
    lam = (0.56 + 0.2) * H * W * T * 1e-6
    assert abs(len(ev) - lam) < 5 * np.sqrt(lam)
    on_expected = (0.2 + 0.56 * 0.54) / 0.76
    assert abs(ev.p.mean() - on_expected) < 5 * np.sqrt(0.25 / len(ev))
    assert np.all(np.diff(ev.t) >= 0)
    ev2 = IdealModel((H, W), shot_noise_rate_hz=0.56, shot_noise_on_fraction=0.54,
                     leak_rate_hz=0.2, seed=2).simulate(ts, fr)
    assert np.array_equal(ev.t, ev2.t) and np.array_equal(ev.x, ev2.x)


@pytest.mark.parametrize("B,H,W", [(3, 37, 53), (1, 16, 16), (2, 5, 70)])
def test_frames_to_tiles_is_the_padded_tile_layout(B, H, W):
    from gs2e.events import _kernels as K
    from gs2e.events.models import TILE

    frames = np.random.default_rng(B + H).random((B, H, W), dtype=np.float32)
    ty, tx = -(-H // TILE), -(-W // TILE)
    padded = np.zeros((B, ty * TILE, tx * TILE), np.float32)
    padded[:, :H, :W] = frames
    ref = (padded.reshape(B, ty, TILE, tx, TILE).transpose(1, 3, 0, 2, 4)
           .reshape(ty * tx * B, TILE, TILE))  # tile-major, then frame
    out = np.full((ty * tx * B, TILE, TILE), np.nan, np.float32)
    K.frames_to_tiles(frames, out)
    np.testing.assert_array_equal(out, ref)


def test_an_event_model_registered_alone_is_built_and_read_back():
    """A toy model added through register_model alone: make_model builds it from
    the config, log_contrast, the sampling bound and the exports' log signal
    come from its own declarations; the built-in names are the schema's enum."""
    import json
    from pathlib import Path

    import yaml

    from gs2e.events.models import MODELS, log_contrast, register_model
    from gs2e.events.rendered import bound_log
    from gs2e.export.event3dgs import LogSignal

    class DoubledIdeal(IdealModel):
        name = "doubled_ideal"

        @classmethod
        def from_config(cls, cfg, shape, **common):
            common.update(theta_on=2 * common["theta_on"], theta_off=2 * common["theta_off"])
            return cls(shape, log_eps=cfg.log_eps, **common)

        @classmethod
        def log_contrast(cls, cfg, on, off):
            return 2 * on, 2 * off, float(cfg.log_eps)

        @classmethod
        def sampling_step(cls, cfg, theta):
            return 2.0 * theta

    schema = yaml.safe_load(Path("gs2e/schemas/config.schema.yaml").read_text())
    assert set(schema["properties"]["events"]["properties"]["model"]["enum"]) == set(MODELS)
    register_model(DoubledIdeal)
    try:
        cfg = {**load_section("events", '{"model": "ideal", "theta_on": 0.1, "theta_off": 0.1}'),
               "model": "doubled_ideal"}
        ts = np.arange(0, 100_001, 1000, dtype=np.int64)
        fr = np.exp(np.linspace(0, 1.2, len(ts)))[:, None, None] * np.full((1, 2, 3), 0.2) - 1e-3
        counts = {}
        for name in ("ideal", "doubled_ideal"):
            m, _ = make_model(event_settings({**cfg, "model": name}), (2, 3), 0)
            counts[name] = len(m.simulate(ts, fr.astype(np.float32)))
        assert isinstance(make_model(event_settings(cfg), (2, 3), 0)[0], DoubledIdeal)
        assert counts["ideal"] == 6 * 12 and counts["doubled_ideal"] == 6 * 6
        assert log_contrast(event_settings(cfg))[0] == pytest.approx(0.2)
        ideal = event_settings({**cfg, "model": "ideal"})
        assert bound_log(event_settings(cfg)) == pytest.approx(2 * bound_log(ideal))
        sig = LogSignal({"model": "doubled_ideal", "theta/on": np.full((2, 3), 0.2),
                         "theta/off": np.full((2, 3), 0.2),
                         "metadata": json.dumps({"config": cfg})}, (2, 3), "toy")
        assert sig.offset == cfg["log_eps"] and np.all(sig.step_on == 0.2)
    finally:
        MODELS.pop("doubled_ideal")
