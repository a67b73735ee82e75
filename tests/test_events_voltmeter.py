"""DVS-Voltmeter model: first-passage laws, polarity, determinism, edge cases."""

import math

import numba
import numpy as np
import pytest
from numba import njit
from scipy import stats

from gs2e.common.errors import ConfigError, InputError
from gs2e.events import _kernels as K
from gs2e.events.models import Events, VoltmeterModel
from gs2e.events.presets import PRESETS, Preset, effective_threshold, effective_threshold_report
from gs2e.events.synthetic import standard_sequence


def _preset(mu_per_us, sigma):
    # k1 = k3 = k5 = 0: drift = k4, diffusion = k6 for any frame
    return Preset("test", (0.0, 1.0, 0.0, mu_per_us, 0.0, sigma), 1.0, 1.0, "test units")


def _first_events(mu, sigma, theta_on=1.0, theta_off=1.0, n_side=100, T=2_000_000, seed=1):
    m = VoltmeterModel((n_side, n_side), preset=_preset(mu, sigma), theta_on=theta_on,
                       theta_off=theta_off, max_events_per_pixel=1, seed=seed)
    f = np.full((n_side, n_side), 0.5, np.float32)
    ev = m.simulate([0, T], np.stack([f, f]))
    pix = ev.y.astype(np.int64) * n_side + ev.x
    assert len(np.unique(pix)) == len(pix)  # one event per pixel at most
    return ev, n_side * n_side


def _ig(mean, shape):
    return stats.invgauss(mu=mean / shape, scale=shape)


@pytest.mark.parametrize("mu", [1e-5, -1e-5])
def test_first_passage_matches_inverse_gaussian(mu):
    sigma = 2e-3
    ev, n = _first_events(mu, sigma)
    assert len(ev) > 0.999 * n
    # theta_on = theta_off = 1 and residual 0: whatever the polarity, the
    # first-passage time is IG(1/|mu|, 1/sigma^2)
    res = stats.kstest(ev.t.astype(float), _ig(1 / abs(mu), 1 / sigma**2).cdf)
    assert res.pvalue > 1e-3, res
    on = ev.p.mean()
    assert (on > 0.99) if mu > 0 else (on < 0.01)


def test_first_passage_zero_drift_is_levy():
    sigma, T = 2e-3, 2_000_000
    ev, n = _first_events(0.0, sigma, T=T)
    c = 1 / sigma**2
    F = stats.levy(scale=c).cdf
    # only crossings before T are seen: compare with the truncated law
    assert abs(len(ev) / n - F(T)) < 5 * math.sqrt(F(T) * (1 - F(T)) / n)
    res = stats.kstest(ev.t.astype(float), lambda t: F(t) / F(T))
    assert res.pvalue > 1e-3, res
    assert abs(ev.p.mean() - 0.5) < 5 * math.sqrt(0.25 / len(ev))


@pytest.mark.parametrize("mu", [2e-6, -2e-6, 0.0])
def test_polarity_matches_two_barrier_probability(mu):
    sigma, a, b = 2e-3, 0.6, 1.4  # thresholds a (ON), b (OFF), residual 0
    ev, n = _first_events(mu, sigma, theta_on=a, theta_off=b, T=50_000_000)
    z = 2 * mu / sigma**2
    p_on = b / (a + b) if mu == 0 else (math.exp(z * b) - 1) / (math.exp(z * b) - math.exp(-z * a))
    m = len(ev)
    assert m > 0.95 * n
    assert abs(ev.p.mean() - p_on) < 5 * math.sqrt(p_on * (1 - p_on) / m), (ev.p.mean(), p_on)
    if mu != 0:
        # ON crossings: time law IG(a / |mu|, a^2 / sigma^2) (single-barrier law given polarity)
        t_on = ev.t[ev.p == 1].astype(float)
        res = stats.kstest(t_on, _ig(a / abs(mu), a**2 / sigma**2).cdf)
        assert res.pvalue > 1e-3, res


def test_p_on_is_stable_for_huge_drift():
    with np.errstate(all="raise"):
        for z_scale in (1e3, 1e8, 1e300):
            for sgn in (1, -1):
                p = K.p_on_two_barrier(sgn * z_scale, 1.0, 0.7, 1.3)
                assert p == (1.0 if sgn > 0 else 0.0) or 0 <= p <= 1e-300
        assert K.p_on_two_barrier(1e-300, 1.0, 0.3, 0.7) == pytest.approx(0.7)
        assert K.p_on_two_barrier(0.0, 0.0, 0.3, 0.7) == pytest.approx(0.7)
    # symmetric check against the direct formula where it does not overflow
    for mu in (-3.0, -0.1, 0.2, 2.0):
        z = 2 * mu
        direct = (math.exp(z * 1.3) - 1) / (math.exp(z * 1.3) - math.exp(-z * 0.7))
        assert K.p_on_two_barrier(mu, 1.0, 0.7, 1.3) == pytest.approx(direct, rel=1e-12)


@njit(cache=True)
def _simulate_hits(n, eps, c, sigma, dt, T, seed):
    """Euler paths with exact Gaussian increments and the Brownian-bridge
    crossing correction; returns hit times (inf if no hit before T)."""
    out = np.full(n, np.inf)
    for i in range(n):
        st = K.stream_state(seed, 0, i, 7)
        x = 0.0
        t = 0.0
        sq = sigma * math.sqrt(dt)
        while t < T:
            st, z = K.normal_zig(st)
            x1 = x + c * dt + sq * z
            hit = x1 >= eps
            if not hit:
                st, u = K.uniform_open(st)
                hit = u < math.exp(-2.0 * (eps - x) * (eps - x1) / (sigma * sigma * dt))
            if hit:
                st, u = K.uniform_open(st)
                out[i] = t + u * dt
                break
            x = x1
            t += dt
    return out


def test_negative_drift_conditional_law_against_simulation():
    """Derivation check: with drift away from the barrier, the barrier is hit
    with probability exp(-2 |c| eps / sigma^2) and, given a hit, the time is
    IG(eps / |c|, eps^2 / sigma^2)."""
    eps, c, sigma, T = 1.0, -0.5, 1.0, 60.0
    t = _simulate_hits(6000, eps, c, sigma, 2e-3, T, 11)
    hits = t[np.isfinite(t)]
    p_hit = math.exp(-2 * abs(c) * eps / sigma**2)
    assert abs(len(hits) / len(t) - p_hit) < 5 * math.sqrt(p_hit * (1 - p_hit) / len(t))
    res = stats.kstest(hits, _ig(eps / abs(c), eps**2 / sigma**2).cdf)
    assert res.pvalue > 1e-3, res


@njit(cache=True)
def _normals(n, seed):
    out = np.empty(n)
    st = K.stream_state(seed, 0, 0, 5)
    for i in range(n):
        st, out[i] = K.normal_zig(st)
    return out


def test_ziggurat_normals():
    x = _normals(1_000_000, 3)
    assert stats.kstest(x, "norm").pvalue > 1e-3
    tail = np.abs(x) > 3.6541528853610088  # beyond the base strip
    assert abs(tail.mean() - 2 * stats.norm.sf(3.6541528853610088)) < 5 * math.sqrt(2.6e-4 / 1e6)
    t = np.abs(x[tail])
    assert stats.kstest(t, lambda v: 1 - stats.norm.sf(v) / stats.norm.sf(3.6541528853610088)).pvalue > 1e-3


@njit(cache=True)
def _sample_fpt(n, eps, c, sigma, seed):
    out = np.empty(n)
    st = K.stream_state(seed, 0, 0, 9)
    for i in range(n):
        st, z = K.normal_zig(st)
        st, u = K.uniform_open(st)
        out[i] = K.first_passage_time(z * z, u, eps, c, sigma)
    return out


@pytest.mark.parametrize("eps,c,sigma", [(1.0, 2.0, 0.5), (0.3, 1e-3, 2.0), (2.0, 50.0, 0.01)])
def test_first_passage_sampler_ks(eps, c, sigma):
    x = _sample_fpt(20000, eps, c, sigma, 5)
    assert np.all(np.isfinite(x)) and np.all(x > 0)
    res = stats.kstest(x, _ig(eps / c, (eps / sigma) ** 2).cdf)
    assert res.pvalue > 1e-3, res


def test_residual_carried_between_frames():
    """Splitting one interval into many frames must not change the rate: the
    residual voltage carries the progress towards the threshold."""
    mu, sigma = 1e-5, 1e-4  # nearly deterministic: one event every ~1e5 us
    pr = _preset(mu, sigma)
    f = np.full((30, 30), 0.5, np.float32)
    m1 = VoltmeterModel((30, 30), preset=pr, seed=3)
    ev1 = m1.simulate([0, 1_000_000], np.stack([f, f]))
    m2 = VoltmeterModel((30, 30), preset=pr, seed=3)
    ts = np.arange(0, 1_000_001, 1000)
    ev2 = m2.simulate(ts, np.repeat(f[None], len(ts), 0))
    # ~10 crossings per pixel (the 10th falls at ~T +- 1e4 us, about half of them in)
    assert 9.0 * 900 <= len(ev1) <= 10.0 * 900
    assert len(ev2) == pytest.approx(len(ev1), abs=5 * math.sqrt(len(ev1) * 0.1) + 10)
    assert ev2.p.all()


def _run(seq, threads=None, batch=32, seed=7, preset="dvs346", **kw):
    if threads:
        numba.set_num_threads(threads)
    try:
        m = VoltmeterModel(seq[1].shape[1:], preset=preset, seed=seed, **kw)
        out = []
        for i in range(0, len(seq[0]), batch):
            out.append(m.process_batch(seq[0][i:i + batch], seq[1][i:i + batch]))
        out.append(m.flush())
        return Events.concat(out)
    finally:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)


@pytest.fixture(scope="module")
def small_seq():
    fr = list(standard_sequence(n_frames=60, width=96, height=72))
    return np.array([t for t, _ in fr]), np.stack([f for _, f in fr])


def _bytes(ev):
    return ev.t.tobytes() + ev.x.tobytes() + ev.y.tobytes() + ev.p.tobytes()


def test_deterministic_across_threads_and_batches(small_seq):
    a = _run(small_seq, threads=1, batch=60)
    b = _run(small_seq, threads=numba.config.NUMBA_NUM_THREADS, batch=7)
    c = _run(small_seq, batch=1)
    assert len(a) > 1000
    assert _bytes(a) == _bytes(b) == _bytes(c)
    d = _run(small_seq, seed=8)
    assert _bytes(d) != _bytes(a)
    assert np.all(np.diff(a.t) >= 0)


def test_event_count_scales_with_inverse_theta(small_seq):
    # natural sequence: ~1/theta up to the quantisation of finite sweeps
    n1 = len(_run(small_seq, theta_on=0.5, theta_off=0.5))
    n05 = len(_run(small_seq, theta_on=0.25, theta_off=0.25))
    assert 1.9 <= n05 / n1 <= 2.35
    # steady exponential ramp (x4 in 0.2 s): the voltage rises by
    # k1 ln((L1 + k2) / (L0 + k2)) ~ 6.05 (0..255 units, k2 = 20)
    ts = np.arange(0, 200_001, 1000)
    lum = 0.2 * 4.0 ** (ts / 200_000.0)
    fr = np.repeat(lum[:, None, None], 40 * 40, 1).reshape(len(ts), 40, 40).astype(np.float32)
    counts = [len(_run((ts, fr), theta_on=th, theta_off=th)) for th in (1.0, 0.5, 0.25)]
    per_px = np.array(counts) / 1600
    expected = 5.265 * math.log((0.8 * 255 + 20) / (0.2 * 255 + 20)) / np.array([1.0, 0.5, 0.25])
    assert np.all(np.abs(per_px - expected) <= 1.0), (per_px, expected)
    assert counts[2] / counts[1] == pytest.approx(2.0, rel=0.06)


def test_black_saturated_constant_pixels():
    H, W, T = 20, 30, 3_000_000
    ts = np.arange(0, T + 1, 10_000)
    for val in (0.0, 1.0, 0.37):
        f = np.full((len(ts), H, W), val, np.float32)
        m = VoltmeterModel((H, W), preset="dvs346", seed=1)
        ev = m.simulate(ts, f)
        mu = 1e-7 + 5e-9 * val * 255  # leak drift per us (k4 + k5 L)
        # constant pixels only leak: quasi-periodic ON events every 1/mu us
        # (jitter ~1e4 us), so every pixel has floor(T mu) of them
        counts = np.bincount(ev.y.astype(int) * W + ev.x, minlength=H * W)
        assert np.all(counts == math.floor(T * mu)), (val, np.unique(counts), T * mu)
        assert np.all(ev.p == 1)
        assert np.isfinite(m.res).all() and (m.res <= 1).all() and (m.res >= -1).all()


def test_timestamps_exact_beyond_2_24_us(small_seq):
    ts, fr = small_seq
    big = ts + (1 << 34) + 3
    a = _run(small_seq)
    b = _run((big, fr))
    # same streams (keyed by frame index) -> the same events shifted exactly
    assert np.array_equal(b.t - a.t, np.full(len(a), (1 << 34) + 3))
    assert np.array_equal(a.x, b.x) and np.array_equal(a.p, b.p)


def test_bad_frames_rejected():
    m = VoltmeterModel((4, 5), preset="dvs346")
    f = np.zeros((4, 5), np.float32)
    m.process(0, f)
    bad = f.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        m.process(10, bad)
    with pytest.raises(InputError, match="shape"):
        m.process(10, np.zeros((5, 4)))
    with pytest.raises(InputError, match="increase"):
        m.process(0, f)
    with pytest.raises(InputError, match=r"\[0, 1\]"):
        m.process(10, f + 2)
    with pytest.raises(InputError, match="integer"):
        m.simulate(np.array([10.5]), f[None])
    m.process(10, f)  # still usable after rejected frames
    with pytest.raises(ConfigError):
        VoltmeterModel((4, 5), preset="nope")
    with pytest.raises(ConfigError):
        VoltmeterModel((4, 5), theta_on=np.zeros((4, 5)))


def test_presets_and_effective_threshold():
    p = PRESETS["dvs346"]
    assert p.k[0] == pytest.approx(5.265)
    assert effective_threshold(p, 1.0, 1.0) == pytest.approx((1 + 20 / 255) / 5.265)
    rows = {r["preset"]: r for r in effective_threshold_report()}
    assert rows["dvs346"]["limit_theta_over_k1"] == pytest.approx(0.19, abs=0.005)
    assert rows["gs2e_paper"]["limit_theta_over_k1"] == pytest.approx(2.0)
    assert PRESETS["gs2e_paper"].time_unit_us == 1e6


@njit(cache=True)
def _simulate_two_barrier(n, a, b, mu, sigma, dt, seed):
    """Exit (time, side) of drifted Brownian motion from (-b, a), fine steps
    with per-step bridge crossing corrections for both barriers."""
    t_out = np.full(n, np.inf)
    up = np.zeros(n, np.bool_)
    s2dt = sigma * sigma * dt
    for i in range(n):
        st = K.stream_state(seed, 1, i, 7)
        x = 0.0
        t = 0.0
        while t < 1e3:
            st, z = K.normal_zig(st)
            x1 = x + mu * dt + sigma * math.sqrt(dt) * z
            st, u1 = K.uniform_open(st)
            st, u2 = K.uniform_open(st)
            hit_up = x1 >= a or u1 < math.exp(-2.0 * (a - x) * (a - x1) / s2dt)
            hit_dn = x1 <= -b or u2 < math.exp(-2.0 * (x + b) * (x1 + b) / s2dt)
            if hit_up or hit_dn:
                st, u = K.uniform_open(st)
                t_out[i] = t + u * dt
                up[i] = hit_up if not hit_dn else (x1 > 0.5 * (a - b))
                break
            x = x1
            t += dt
    return t_out, up


def test_two_barrier_conditional_exit_time_is_not_inverse_gaussian():
    """The documented difference: given exit through the ON barrier, the exit
    time of the two-barrier problem follows the image series, not the
    single-barrier IG that DVS-Voltmeter (and gs2e's voltmeter model) use."""
    a = b = 1.0
    mu, sigma = 0.5, 1.0
    w = a + b
    t, up = _simulate_two_barrier(6000, a, b, mu, sigma, 5e-4, 3)
    z = 2 * mu / sigma**2
    p_on = (math.exp(z * b) - 1) / (math.exp(z * b) - math.exp(-z * a))
    assert abs(up.mean() - p_on) < 5 * math.sqrt(p_on * (1 - p_on) / len(up))

    def g_up(tt):
        k = np.arange(-30, 31)[:, None]
        c = a + 2 * k * w
        dens = (c / (sigma * np.sqrt(2 * np.pi * tt**3)) * np.exp(-c**2 / (2 * sigma**2 * tt))).sum(0)
        return dens * np.exp(mu * a / sigma**2 - mu**2 * tt / (2 * sigma**2))

    grid = np.linspace(1e-4, 40, 400_001)
    cdf = np.concatenate([[0], np.cumsum(0.5 * (g_up(grid[1:]) + g_up(grid[:-1])) * np.diff(grid))])
    assert cdf[-1] == pytest.approx(p_on, rel=1e-3)  # the series integrates to p_on
    t_up = t[up]
    res_series = stats.kstest(t_up, lambda x: np.interp(x, grid, cdf / cdf[-1]))
    res_ig = stats.kstest(t_up, _ig(a / mu, a**2 / sigma**2).cdf)
    assert res_series.pvalue > 1e-3, res_series
    assert res_ig.pvalue < 1e-8, res_ig


def _series_cdf_up(a, b, mu, sigma, t_max=40.0, n=400_001):
    """CDF (unnormalised, ends at p_on) of the two-barrier exit time through
    the upper barrier, from the image series."""
    w = a + b
    grid = np.linspace(1e-4, t_max, n)

    def g_up(tt):
        k = np.arange(-30, 31)[:, None]
        c = a + 2 * k * w
        dens = (c / (sigma * np.sqrt(2 * np.pi * tt**3)) * np.exp(-c**2 / (2 * sigma**2 * tt))).sum(0)
        return dens * np.exp(mu * a / sigma**2 - mu**2 * tt / (2 * sigma**2))

    cdf = np.concatenate([[0], np.cumsum(0.5 * (g_up(grid[1:]) + g_up(grid[:-1])) * np.diff(grid))])
    return grid, cdf


def _first_events_tu(mu, sigma, exit_law, ts, n_side=80, seed=2):
    """First event per pixel; model time unit 1e5 us (so mu, sigma are per 0.1 s)."""
    pr = Preset("t", (0.0, 1.0, 0.0, mu, 0.0, sigma), 1.0, 1e5, "test")
    m = VoltmeterModel((n_side, n_side), preset=pr, exit_law=exit_law, max_events_per_pixel=1,
                       seed=seed)
    f = np.full((n_side, n_side), 0.5, np.float32)
    out = []
    for i in range(0, len(ts), 256):
        out.append(m.process_batch(ts[i:i + 256], np.repeat(f[None], len(ts[i:i + 256]), 0)))
    out.append(m.flush())
    ev = Events.concat(out)
    # max_events_per_pixel is per interval: keep each pixel's first event
    pix = ev.y.astype(np.int64) * n_side + ev.x
    _, first = np.unique(pix, return_index=True)
    return Events(ev.t[first], ev.x[first], ev.y[first], ev.p[first]), n_side * n_side


def test_two_barrier_exit_law_is_exact():
    mu, sigma, a = 0.5, 1.0, 1.0
    ts = np.array([0, 4_000_000], np.int64)  # 40 model units
    ev, n = _first_events_tu(mu, sigma, "two_barrier", ts)
    z = 2 * mu / sigma**2
    p_on = (math.exp(z) - 1) / (math.exp(z) - math.exp(-z))
    assert len(ev) > 0.999 * n
    assert abs(ev.p.mean() - p_on) < 5 * math.sqrt(p_on * (1 - p_on) / len(ev))
    grid, cdf = _series_cdf_up(a, a, mu, sigma)
    t_on = ev.t[ev.p == 1] / 1e5
    res = stats.kstest(t_on, lambda x: np.interp(x, grid, cdf / cdf[-1]))
    assert res.pvalue > 1e-3, res
    assert stats.kstest(t_on, _ig(a / mu, a**2 / sigma**2).cdf).pvalue < 1e-8


@pytest.mark.parametrize("exit_law", ["single_barrier", "two_barrier"])
def test_frame_splitting(exit_law):
    """One long interval vs 400 short ones. The exact two-barrier law does not
    depend on how time is cut into frames. DVS-Voltmeter's law does: it draws
    the polarity anew in every interval and then lets the voltage drift towards
    the chosen barrier, so with drift against the noise (here mu < 0) short
    frames give earlier first events. This test documents that defect."""
    mu, sigma = -0.3, 1.0
    long_ev, _ = _first_events_tu(mu, sigma, exit_law, np.array([0, 2_000_000]), n_side=60)
    ts = np.linspace(0, 2_000_000, 401).astype(np.int64)
    short_ev, _ = _first_events_tu(mu, sigma, exit_law, ts, n_side=60, seed=9)
    p_same = stats.ks_2samp(long_ev.t, short_ev.t).pvalue
    if exit_law == "two_barrier":
        assert p_same > 1e-3
        pl, ps = long_ev.p.mean(), short_ev.p.mean()
        assert abs(pl - ps) < 5 * math.sqrt(pl * (1 - pl) * (1 / len(long_ev) + 1 / len(short_ev)))
    else:
        assert p_same < 1e-10
        assert np.median(short_ev.t) < 0.8 * np.median(long_ev.t)


@pytest.mark.parametrize("n", [0, 1, 2, 17, 100_003])
def test_sort_events_is_a_stable_time_row_column_sort_for_any_thread_count(n):
    rng = np.random.default_rng(n)
    H, W = 260, 346
    # few distinct times: many exact ties on (t, y, x), which must keep input order
    t = (rng.integers(0, 5, n) * 3_000_000_000 + 10**12).astype(np.int64)  # keys need 6 digits
    x = rng.integers(0, 3, n).astype(np.uint16) + np.uint16(W - 3)
    y = rng.integers(0, 2, n).astype(np.uint16) + np.uint16(H - 2)
    p = np.arange(n, dtype=np.int64).astype(np.uint8)  # marks input order within ties
    order = np.lexsort((np.arange(n), x, y, t))
    want = (t[order], x[order], y[order], p[order])
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        numba.set_num_threads(threads)
        try:
            got = K.sort_events(t, x, y, p, H, W)
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
        for g, w in zip(got, want):
            assert g.dtype == w.dtype and np.array_equal(g, w)
