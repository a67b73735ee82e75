"""The benchmark's pieces on hard cases: the exact exposure integral, EDI's
inversion, its threshold search, video integration, method loading, the
summary table and the report's tables."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from gs2e.bench import deblur as D
from gs2e.bench.video import reconstruct
from gs2e.common.color import linear_to_srgb, srgb_to_linear
from gs2e.common.errors import ConfigError


def _brute_mean_exp(t, x, y, steps, t0, t1, t_ref, shape, n=200_001):
    """The same integral on a dense grid (independent of the kernel's bookkeeping)."""
    tau = np.linspace(t0, t1, n)
    out = np.ones(shape)
    for yy in range(shape[0]):
        for xx in range(shape[1]):
            m = (x == xx) & (y == yy)
            if not m.any():
                continue
            tt, ss = t[m], steps[m]
            cum = np.concatenate([[0.0], np.cumsum(ss)])
            e_tau = cum[np.searchsorted(tt, tau, side="right")]
            e_ref = cum[np.searchsorted(tt, t_ref, side="right")]
            out[yy, xx] = np.trapezoid(np.exp(e_tau - e_ref), tau) / (t1 - t0)
    return out


def test_exposure_integral_matches_brute_force_with_boundary_events():
    rng = np.random.default_rng(3)
    shape, t0, t1, t_ref = (3, 4), 1000.0, 21000.0, 11000.0
    n = 300
    t = np.sort(np.concatenate([rng.uniform(t0, t1, n - 4), [t0, t_ref, t_ref, t1]]))
    x = rng.integers(0, shape[1], n)
    y = rng.integers(0, shape[0], n)
    p = rng.integers(0, 2, n)
    steps = D.log_steps(p, x, y, rng.uniform(0.1, 0.5, shape), rng.uniform(0.1, 0.5, shape))
    got = D.exposure_mean_exp(t, x, y, steps, t0, t1, t_ref, shape)
    want = _brute_mean_exp(t, x, y, steps, t0, t1, t_ref, shape)
    np.testing.assert_allclose(got, want, rtol=2e-4)


def test_exposure_integral_degenerate_cases():
    e = np.empty(0)
    assert (D.exposure_mean_exp(e, e, e, e, 0.0, 100.0, 50.0, (2, 2)) == 1).all()  # no events
    one = np.array([10.0])
    assert (D.exposure_mean_exp(one, [0], [0], [0.3], 50.0, 50.0, 50.0, (1, 1)) == 1).all()  # T = 0
    # thousands of ON events on one pixel: clamped, finite, no overflow
    t = np.linspace(0, 100, 5000)
    m = D.exposure_mean_exp(t, np.zeros(5000, int), np.zeros(5000, int), np.ones(5000), 0.0, 100.0,
                            0.0, (1, 1))
    assert np.isfinite(m).all() and m[0, 0] > 1e200
    lat = D.edi_latent(np.full((1, 1, 3), 0.5), m, 1e-3)
    assert np.isfinite(lat).all() and lat.min() >= 0


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_exposure_levels_give_the_integral_at_every_theta(seed):
    """The theta search's form (levels once, then one exp per stretch) against
    the direct integral, for one threshold: events before t0, after t1, at t0,
    t_ref and t1, several at one time, thousands on one pixel (clamped exp)."""
    from gs2e.bench import _kernels as K

    rng = np.random.default_rng(seed)
    shape, t0, t1, t_ref = (3, 5), 1000.0, 21000.0, 11000.0
    n = 400
    t = np.sort(np.concatenate([rng.uniform(0, 25000, n - 8), [t0, t0, t_ref, t_ref, t1, t1, 5e3, 5e3]]))
    x, y = rng.integers(0, shape[1], n), rng.integers(0, shape[0], n)
    x[:4] = y[:4] = 0  # several events of one pixel before t0
    sign = np.where(rng.integers(0, 2, n) > 0, 1, -1)
    lv = K.exposure_levels(t, x, y, sign, t0, t1, t_ref, *shape)
    assert (lv[2] > 0).all() and len(lv[0]) <= 2 * n
    for theta in (0.02, 0.3, 1.5):
        want = D.exposure_mean_exp(t, x, y, sign * theta, t0, t1, t_ref, shape)
        np.testing.assert_allclose(K.mean_exp_levels(*lv, theta, t1 - t0, *shape), want, rtol=1e-12)
    e = np.empty(0, np.int64)
    assert (K.mean_exp_levels(*K.exposure_levels(np.empty(0), e, e, e, 0.0, 100.0, 50.0, 2, 2), 0.3,
                              100.0, 2, 2) == 1).all()  # no events
    lv = K.exposure_levels(np.array([10.0]), np.zeros(1, np.int64), np.zeros(1, np.int64),
                           np.ones(1, np.int64), 50.0, 50.0, 50.0, 1, 1)
    assert len(lv[0]) == 0  # T = 0: nothing to integrate
    many = np.linspace(0, 100, 5000)
    z = np.zeros(5000, np.int64)
    lv = K.exposure_levels(many, z, z, np.ones(5000, np.int64), 0.0, 100.0, 0.0, 1, 1)
    m = K.mean_exp_levels(*lv, 1.0, 100.0, 1, 1)
    assert np.isfinite(m).all() and m[0, 0] > 1e200


def test_edi_inverts_an_exact_step():
    """A pixel whose linear intensity steps from a to b (one ON event of exactly
    the log step) at ts inside the exposure: EDI returns a before ts, b after."""
    eps, a, theta = 1e-3, 0.2, 0.3
    b = (a + eps) * math.exp(theta) - eps
    t0, t1, ts = 0.0, 20_000.0, 6_000.0
    B = (a * (ts - t0) + b * (t1 - ts)) / (t1 - t0)
    blur = linear_to_srgb(np.full((1, 1, 3), B))
    for t_ref, want in ((2_000.0, a), (15_000.0, b)):
        m = D.exposure_mean_exp([ts], [0], [0], [theta], t0, t1, t_ref, (1, 1))
        lat = srgb_to_linear(D.edi_latent(blur, m, eps))
        np.testing.assert_allclose(lat, want, rtol=1e-9)
    # polarity and scalar / map thresholds
    np.testing.assert_array_equal(D.log_steps(np.array([1, 0]), np.array([0, 1]), np.array([0, 0]),
                                              np.array([[0.1, 0.2]]), 0.5), [0.1, -0.5])


def _moving_bar(theta_true: float, shape=(16, 48), speed_px_per_us=0.0004, exposure=20_000.0,
                t_frames=(15_000.0, 45_000.0), t_end=60_000.0):
    """A bright bar crossing dark ground at constant speed: exact blurred frames
    (fine time averages) at ``t_frames`` and ideal events of threshold theta_true."""
    H, W = shape
    eps = 1e-3
    xs = np.arange(W) + 0.5

    def image(t):  # linear luminance, soft edges
        pos = 8.0 + speed_px_per_us * t
        v = 0.05 + 0.75 / (1 + np.exp(-(xs - pos) / 0.7)) * (1 / (1 + np.exp((xs - pos - 10) / 0.7)))
        return np.tile(v, (H, 1))

    ts = np.linspace(0, t_end, 12001)
    logs = np.log(np.array([image(t)[0] for t in ts]) + eps)  # (T, W)
    ev_t, ev_x, ev_p = [], [], []
    ref = logs[0].copy()
    for k in range(1, len(ts)):
        for j in range(W):
            while logs[k, j] - ref[j] >= theta_true:
                ref[j] += theta_true
                ev_t.append(ts[k]), ev_x.append(j), ev_p.append(1)
            while ref[j] - logs[k, j] >= theta_true:
                ref[j] -= theta_true
                ev_t.append(ts[k]), ev_x.append(j), ev_p.append(0)
    # every row sees the same events
    T = np.repeat(ev_t, H)
    o = np.argsort(T, kind="stable")
    X, Y, P = np.repeat(ev_x, H)[o], np.tile(np.arange(H), len(ev_t))[o], np.repeat(ev_p, H)[o]

    def srgb(lin):
        return linear_to_srgb(np.repeat(lin[..., None], 3, axis=2))

    blurs = [srgb(np.mean([image(t) for t in np.linspace(tf - exposure / 2, tf + exposure / 2, 2001)],
                          axis=0)) for tf in t_frames]
    sharps = [srgb(image(tf)) for tf in t_frames]
    return blurs, sharps, (T[o], X, Y, P), eps


@pytest.mark.parametrize("theta_true", [0.1, 0.3])
def test_chosen_threshold_is_near_the_true_one_and_deblurs(theta_true):
    from gs2e.bench.methods import BenchInput, DeblurSettings, edi_chosen
    from gs2e.events.models import Events

    (ba, bb), (sa, _), (t, x, y, p), eps = _moving_bar(theta_true)
    theta = D.choose_theta(ba, bb, t, x, y, p, 15_000.0, 45_000.0, 20_000.0, eps, 0.02, 1.5, 12)
    assert 0.7 * theta_true <= theta <= 1.4 * theta_true, theta
    ev = Events(t.astype(np.int64), x.astype(np.uint16), y.astype(np.uint16), p.astype(np.uint8))
    exp = (t >= 5_000) & (t < 25_000)
    inp = BenchInput("deblur", 0, 15_000, Events(ev.t[exp], ev.x[exp], ev.y[exp], ev.p[exp]), 5_000,
                     25_000, np.eye(4), np.eye(3), np.full((16, 48), theta_true),
                     np.full((16, 48), theta_true), eps, 20_000.0, ba)
    lat, th = edi_chosen(inp, DeblurSettings(0.02, 1.5, 12), bb, 45_000, ev)
    assert th == theta
    assert np.mean((lat - sa) ** 2) < 0.25 * np.mean((ba - sa) ** 2)


def test_chosen_threshold_without_events_or_partner():
    blur = np.random.default_rng(0).random((5, 6, 3))
    e = np.empty(0)
    assert math.isnan(D.choose_theta(blur, blur, e, e, e, e, 0.0, 1.0, 0.5, 1e-3, 0.02, 1.5, 8))
    assert math.isnan(D.choose_theta(np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), [0.5], [0], [0], [1],
                                     0.0, 1.0, 0.5, 1e-3, 0.02, 1.5, 8))  # nothing well exposed


def test_video_integration_and_complementary_filter():
    eps, key = 1e-3, np.full((1, 2), 0.2)
    t = np.array([100, 200, 300])
    x, y = np.array([0, 0, 1]), np.zeros(3, int)
    steps = np.array([0.5, 0.5, -0.25])
    q = np.array([150, 250, 1_000_000])
    frames = list(reconstruct(key, eps, t, x, y, steps, 0, q, 0.0))
    g0 = math.log(0.2 + eps)
    np.testing.assert_allclose(frames[0][0, 0], math.exp(g0 + 0.5) - eps)
    np.testing.assert_allclose(frames[1][0], [math.exp(g0 + 1.0) - eps, 0.2])
    np.testing.assert_allclose(frames[2][0], [math.exp(g0 + 1.0) - eps, math.exp(g0 - 0.25) - eps])
    # complementary filter: the deviation from the keyframe decays at alpha
    alpha = 2.0
    cf = list(reconstruct(key, eps, t[:1], x[:1], y[:1], steps[:1], 0, np.array([100, 600_100]), alpha))
    np.testing.assert_allclose(cf[0][0, 0], math.exp(g0 + 0.5) - eps)
    np.testing.assert_allclose(cf[1][0, 0], math.exp(g0 + 0.5 * math.exp(-alpha * 0.6)) - eps, rtol=1e-12)
    # events at or before the keyframe are not applied
    before = list(reconstruct(key, eps, np.array([0]), np.array([0]), np.array([0]), np.array([1.0]),
                              0, np.array([10]), 0.0))
    np.testing.assert_allclose(before[0], key)


def test_method_loading_errors_name_the_method():
    from gs2e.bench.methods import as_srgb01, load_method

    assert load_method("bench_user_methods:mean_of_neighbours").__name__ == "mean_of_neighbours"
    for spec, msg in (("nocolon", "package.module:function"), ("no_such_mod_xyz:f", "cannot import"),
                      ("bench_user_methods:CALLS", "no callable")):
        with pytest.raises(ConfigError, match=msg):
            load_method(spec)
    with pytest.raises(ConfigError, match="shape"):
        as_srgb01(np.zeros((3, 3)), (4, 4), "method m")
    with pytest.raises(ConfigError, match="non-finite"):
        as_srgb01(np.full((4, 4), np.nan), (4, 4), "method m")
    np.testing.assert_allclose(as_srgb01(np.full((2, 2, 3), 255, np.uint8), (2, 2), "m"), 1.0)


def test_config_checks():
    from gs2e.config import load_config, scene_config

    with pytest.raises(ConfigError, match="bench.edi_theta_min"):
        load_config({"bench": {"edi_theta_min": 2.0, "edi_theta_max": 1.0}})
    with pytest.raises(ConfigError, match="bench.methods: module 'no_such_mod_xyz'"):
        load_config({"bench": {"methods": ["no_such_mod_xyz:f"]}})
    with pytest.raises(ConfigError, match="bench.methods"):
        load_config({"bench": {"methods": ["not a spec"]}})
    with pytest.raises(ConfigError, match="render.write_blur"):
        scene_config(load_config({}), {"scene_id": "s", "overrides":
                                       "bench.tasks=[deblur];render.write_blur=false"})


def _rows(task, method, psnrs, t_rel):
    mse = [10 ** (-p / 10) for p in psnrs]
    return [{"scene_id": "s", "trajectory": "base_strong", "preset": "strong", "task": task,
             "model": "ideal", "method": method, "frame": i, "t_us": int(t * 1e6), "t_rel_s": t,
             "motion_px": 20.0 + i, "n_events": 1, "psnr": p, "ssim": 0.9, "mse": m,
             "theta": 0.2, "time_s": 0.01} for i, (p, m, t) in enumerate(zip(psnrs, mse, t_rel))]


def test_summary_pools_errors_and_reports_drift():
    from gs2e.bench.summary import summarise

    df = pd.DataFrame(_rows("video", "integrate", [30.0, 20.0, 10.0], [0.25, 0.5, 0.75])
                      + _rows("deblur", "blurred", [30.0, 30.0], [0.1, 0.2]))
    rows = {r["task"]: r for r in summarise(df)}
    v = rows["video"]
    assert v["psnr"] == pytest.approx(-10 * math.log10(np.mean([1e-3, 1e-2, 1e-1])))
    assert v["psnr_at_0_5s"] == pytest.approx(20.0) and v["psnr_end"] == pytest.approx(10.0)
    assert v["drift_db_per_s"] == pytest.approx(-40.0)
    assert rows["deblur"]["motion_px_median"] == pytest.approx(20.5)
    short = summarise(pd.DataFrame(_rows("video", "integrate", [30.0, 29.0], [0.05, 0.1])))[0]
    assert math.isnan(short["psnr_at_0_5s"])  # the trajectory ends before 0.5 s
    assert summarise(pd.DataFrame()) == []


def test_report_bench_tables_follow_the_papers_layout():
    from gs2e.bench.summary import summarise
    from gs2e.report.build import bench_tables

    rows = []
    for preset, p in (("mild", 35.0), ("medium", 30.0), ("strong", 25.0)):
        for r in _rows("deblur", "blurred", [p], [0.1]) + _rows("deblur", "edi_oracle", [p + 4], [0.1]):
            rows.append({**r, "preset": preset, "trajectory": f"base_{preset}"})
    tab = bench_tables(pd.DataFrame(summarise(pd.DataFrame(rows))))["deblur"]
    assert list(tab.columns) == ["events", "method", "mild", "medium", "strong"]
    assert tab.iloc[1]["strong"] == "29.00 / 0.900"
    assert tab.iloc[-1]["method"].startswith("motion")


def test_report_recon3d_table_shows_cost_and_the_fewest_held_out_frames():
    from gs2e.bench.summary import summarise
    from gs2e.report.build import bench_tables

    rows = []
    for scene, n_held in (("a", 9), ("b", 12)):
        for preset in ("mild", "strong"):
            for r in _rows("recon3d", "event_only", [20.0] * n_held, [0.1] * n_held):
                rows.append({**r, "scene_id": scene, "preset": preset, "trajectory": f"base_{preset}",
                             "mse_raw": 0.01, "psnr_rgb": 20.0, "cpu_s": 120.0, "n_gaussians": 10})
    tab = bench_tables(pd.DataFrame(summarise(pd.DataFrame(rows))))["recon3d"]
    assert tab.iloc[-2]["method"] == "event_only: CPU-minutes" and tab.iloc[-2]["mild"] == "2.0"
    assert tab.iloc[-1]["method"].startswith("held-out frames") and tab.iloc[-1]["strong"] == "9"
