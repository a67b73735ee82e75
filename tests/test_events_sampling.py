"""Temporal sampling of the event signal (gs2e.events.sampling): the global
adaptive sampler on analytic signals, and per-tile clocks on real Gaussian
scenes (bound, static cameras, black regions, Gaussians entering tiles,
byte-identical events for any thread count and batching)."""

from __future__ import annotations

import numba
import numpy as np
import pytest

from gs2e.events.models import TILE, Events, IdealModel, VoltmeterModel
from gs2e.events.sampling import SamplerStats, TileSampler, adaptive_samples, max_log_change
from gs2e.splat.forward import ForwardRenderer

W, H, F = 64, 48, 60.0


# ------------------------------------------------------------ global adaptive sampler
def _ramp_sampler(rate: np.ndarray, bound: float, t1: int = 100_000, dt_min: int = 1, dt_max: int = 20_000):
    """A per-pixel log-linear signal with piecewise rates (per us)."""
    calls = []

    def render_log(t):
        calls.append(t)
        # rate changes at t = 50_000: quiet, then fast
        return np.where(t < 50_000, rate[0] * t, rate[0] * 50_000 + rate[1] * (t - 50_000)) * np.ones(4)

    st = SamplerStats()
    out = list(adaptive_samples(render_log, 0, t1, bound, dt_min, dt_max, 100, st))
    return out, st, calls


def test_adaptive_sampler_never_exceeds_bound_and_idles_when_static():
    out, st, calls = _ramp_sampler(np.array([0.0, 1e-4]), bound=0.1)
    ts = [t for t, _ in out]
    assert ts[0] == 0 and ts[-1] == 100_000 and np.all(np.diff(ts) > 0)
    diffs = [np.max(np.abs(b - a)) for (_, a), (_, b) in zip(out, out[1:])]
    assert max(diffs) <= 0.1 + 1e-12
    assert st.forced == 0
    quiet = [t for t in ts if t < 50_000]
    assert len(quiet) < 12, "static half should take few, growing steps"
    # fast half: 5 log units over 50 ms at <= 0.1 per step needs >= 50 steps
    assert 50 <= len(ts) - len(quiet) <= 80
    assert len(calls) < 1.3 * len(ts)


def test_adaptive_sampler_random_signals_respect_bound_and_never_render_twice():
    rng = np.random.default_rng(0)
    for trial in range(5):
        knots = np.sort(rng.choice(200_000, 8, replace=False))
        vals = rng.normal(size=(8, 16)) * 2
        calls = []

        def render_log(t):
            calls.append(t)
            return np.array([np.interp(t, knots, vals[:, j]) for j in range(16)])

        st = SamplerStats()
        out = list(adaptive_samples(render_log, 0, 200_000, 0.05, 1, 10_000, 50, st))
        diffs = [np.max(np.abs(b - a)) for (_, a), (_, b) in zip(out, out[1:])]
        assert max(diffs) <= 0.05 + 1e-9 and st.forced == 0
        assert len(set(calls)) == len(calls), "no time is rendered twice"
        assert len(calls) == st.accepted + st.rejected - st.reused


def test_adaptive_sampler_reuses_a_rejected_trial():
    """A quiet signal that turns fast: the grown step overshoots and is
    rejected; its frame is then the next sample instead of a wasted render."""
    out, st, calls = _ramp_sampler(np.array([1e-5, 1.6e-5]), bound=0.1)
    assert st.rejected == 1 and st.reused == 1 and len(calls) == st.accepted
    assert {t for t, _ in out} <= set(calls)


def test_sampler_rejects_bad_arguments():
    with pytest.raises(ValueError):
        list(adaptive_samples(lambda t: np.zeros(1), 10, 0, 0.1, 1, 10))
    with pytest.raises(ValueError):
        list(adaptive_samples(lambda t: np.zeros(1), 0, 10, 0.1, 1, 10, outlier_fraction=1.0))


def test_max_log_change_outlier_fraction():
    a = np.zeros(10)
    b = np.arange(10) / 10.0
    assert max_log_change(a, b) == pytest.approx(0.9)
    assert max_log_change(a, -b, 0.1) == pytest.approx(0.8)  # the largest 1 of 10 set aside
    assert max_log_change(a, b, 0.05) == pytest.approx(0.9)  # floor(0.5) = 0 pixels set aside


def test_adaptive_sampler_outlier_fraction_ignores_a_jumping_pixel():
    """One pixel of 100 jumps (a silhouette edge passing it): bounding every
    pixel holds the step at dt_min around the jump; setting 1% of the pixels
    aside keeps the step free and still bounds the other 99 pixels."""
    def render_log(t):
        g = np.full(100, 2e-6 * t)
        g[7] = 5.0 if t >= 30_000 else 0.0
        return g

    runs = {}
    for q in (0.0, 0.01):
        st = SamplerStats()
        out = list(adaptive_samples(render_log, 0, 60_000, 0.05, 10, 5000, 100, st, outlier_fraction=q))
        runs[q] = (out, st)
        others = [np.max(np.abs(np.delete(b - a, 7))) for (_, a), (_, b) in zip(out, out[1:])]
        assert max(others) <= 0.05 + 1e-12
    assert runs[0.0][1].forced >= 1, "a jump cannot be bounded: the step at dt_min is forced"
    assert runs[0.01][1].forced == 0
    assert len(runs[0.01][0]) < len(runs[0.0][0])


# ------------------------------------------------------------ per-tile clocks
def _blobs(centres, rgb, scale=0.03, depth=2.0):
    """Opaque round Gaussians at (x, y) on the plane z = depth (SH degree 0)."""
    from gs2e.splat.init import rgb_to_sh_dc

    c = np.asarray(centres, float)
    n = len(c)
    return {"means": np.c_[c, np.full(n, depth)], "quats": np.tile([1.0, 0, 0, 0], (n, 1)),
            "log_scales": np.full((n, 3), np.log(scale)), "opacity_logits": np.full(n, 6.0),
            "sh": rgb_to_sh_dc(np.broadcast_to(np.asarray(rgb, float), (n, 3)))[:, None, :]}


def _renderer(g):
    return ForwardRenderer(g, 0, F, F, W / 2, H / 2, W, H)


def _pan(vx_per_s, vy_per_s=0.0):
    """Camera translating in x/y at constant speed (scene units per second)."""
    def pose_at(t_us):
        c2w = np.eye(4)
        c2w[0, 3] = vx_per_s * t_us * 1e-6
        c2w[1, 3] = vy_per_s * t_us * 1e-6
        return c2w
    return pose_at


def _textured(n=48, seed=0, extent=1.2):
    rng = np.random.default_rng(seed)
    xs = (np.arange(n) - n / 2 + 0.5) * (2 * extent / n)
    X, Y = np.meshgrid(xs, xs)
    g = _blobs(np.c_[X.ravel(), Y.ravel()], [0.5, 0.5, 0.5], scale=extent / n)
    g["sh"] = rng.uniform(-1.5, 1.5, (n * n, 1, 3))
    return g


def _collect(sampler):
    """Run a sampler; per tile its sample sequence [(t, lum (T, T))]."""
    seq: dict[int, list] = {}
    batches = list(sampler)
    lum0 = sampler.lum0
    for k in range(sampler.n_tiles):
        ty, tx = divmod(k, sampler.renderer.tiles_x)
        blk = np.zeros((TILE, TILE), np.float32)
        part = lum0[ty * TILE:(ty + 1) * TILE, tx * TILE:(tx + 1) * TILE]
        blk[:part.shape[0], :part.shape[1]] = part
        seq[k] = [(sampler.t0_us, blk)]
    for b in batches:
        for s, k in enumerate(b.tiles):
            for i in range(b.offsets[s], b.offsets[s + 1]):
                assert b.t0_us[i] == seq[int(k)][-1][0]
                seq[int(k)].append((int(b.t1_us[i]), b.lum[i]))
    return seq, batches


def _valid(k, tiles_x):
    ty, tx = divmod(k, tiles_x)
    return np.s_[:min(TILE, H - ty * TILE), :min(TILE, W - tx * TILE)]


def test_tile_sampler_bounds_every_pixel_between_its_samples():
    eps, bound = 1e-3, 0.15
    r = _renderer(_textured())
    sp = TileSampler(r, _pan(0.3, 0.1), 0, 60_000, bound, eps, dt_min_us=10, dt_max_us=8000,
                     dt_init_us=400)
    seq, _ = _collect(sp)
    st = sp.stats
    assert st.forced == 0
    worst = 0.0
    for k, s in seq.items():
        assert s[-1][0] == 60_000 and all(b[0] > a[0] for a, b in zip(s, s[1:]))
        v = _valid(k, r.tiles_x)
        g = [np.log(x[1][v].astype(np.float64) + eps) for x in s]
        worst = max(worst, max(np.abs(b - a).max() for a, b in zip(g, g[1:])))
        # every sample is the true image of the tile at its time
    assert worst <= bound + 1e-5
    # every sample is the true image of the tile at its time
    ref = _renderer(_textured())
    from gs2e.events.sampling import image_luminance
    for k in (0, 5, 11):
        for t, lum in seq[k][:: max(1, len(seq[k]) // 4)]:
            full = np.empty((H, W), np.float32)
            image_luminance(ref.render(_pan(0.3, 0.1)(t)), full)
            ty, tx = divmod(k, r.tiles_x)
            np.testing.assert_array_equal(lum[_valid(k, r.tiles_x)],
                                          full[ty * TILE:(ty + 1) * TILE, tx * TILE:(tx + 1) * TILE])


def test_static_camera_samples_each_tile_once():
    r = _renderer(_textured())
    sp = TileSampler(r, _pan(0.0), 0, 1_000_000, 0.1, 1e-3, dt_min_us=20, dt_max_us=5000)
    seq, _ = _collect(sp)
    assert all(len(s) == 2 and s[1][0] == 1_000_000 for s in seq.values())
    assert sp.stats.renders == 2 and sp.stats.rejected == 0


def test_black_regions_and_a_busy_neighbour():
    """Blobs in the left half only: the black right half is sampled once per
    candidate window, the moving textured left half finely; a quiet tile next
    to a busy one keeps its own (coarse) clock."""
    g = _textured(n=24, extent=0.6)
    g["means"][:, 0] -= 0.55  # texture covers the left part of the view only
    r = _renderer(g)
    pose_at = _pan(0.2)
    sp = TileSampler(r, pose_at, 0, 100_000, 0.1, 1e-3, dt_min_us=20, dt_max_us=20_000)
    seq, _ = _collect(sp)
    counts = np.array([len(seq[k]) for k in range(r.n_tiles)]).reshape(r.tiles_y, r.tiles_x)
    right = counts[:, -1]
    busy = counts[:, 0]
    assert right.max() <= 1 + sp.stats.windows, counts
    assert busy.min() > 5 * right.max(), counts
    for k in range(r.n_tiles):
        if k % r.tiles_x == r.tiles_x - 1:
            lum = np.stack([x[1][_valid(k, r.tiles_x)] for x in seq[k]])
            assert np.all(lum == 0.0)  # black background, exactly


def test_a_gaussian_entering_a_quiet_tile_is_caught():
    """A single bright blob enters a black tile between samples (the tile had
    no Gaussians a moment before): the tile's clock must catch it, and the
    ideal model's events must match a dense fixed-rate reference."""
    g = _blobs([[-0.9, 0.0]], [1.0, 1.0, 1.0], scale=0.04)
    pose_at = _pan(-8.0)  # the blob moves right across the view in ~0.25 s
    t1 = 200_000
    eps, th = 1e-3, 0.3
    sp = TileSampler(_renderer(g), pose_at, 0, t1, 0.5 * th, eps, dt_min_us=20, dt_max_us=20_000)
    m = IdealModel((H, W), theta_on=th, theta_off=th, log_eps=eps)
    batches = iter(sp)
    first = next(batches)
    m.start(0, sp.lum0)
    ev = Events.concat([m.process_tiles(first)] + [m.process_tiles(b) for b in batches] + [m.flush()])
    ref_r = _renderer(g)
    from gs2e.events.sampling import image_luminance
    ts = np.arange(0, t1 + 1, 50)
    frames = np.empty((len(ts), H, W), np.float32)
    for i, t in enumerate(ts):
        image_luminance(ref_r.render(pose_at(int(t))), frames[i])
    ref = IdealModel((H, W), theta_on=th, theta_off=th, log_eps=eps).simulate(ts, frames)
    assert len(ref) > 200
    n, n_ref = np.bincount(ev.y * W + ev.x, minlength=H * W), np.bincount(ref.y * W + ref.x, minlength=H * W)
    assert np.abs(n - n_ref).sum() <= 0.05 * len(ref), (np.abs(n - n_ref).sum(), len(ref))
    assert sp.stats.pixel_samples < 0.2 * len(ts) * H * W


@pytest.mark.parametrize("model", ["ideal", "voltmeter"])
def test_tile_events_identical_for_any_threads_and_batching(model):
    def run(threads, batch):
        numba.set_num_threads(threads)
        try:
            sp = TileSampler(_renderer(_textured()), _pan(3.0, 1.0), 0, 30_000, 0.2, 1e-3,
                             dt_min_us=20, batch_intervals=batch)
            cls = IdealModel if model == "ideal" else VoltmeterModel
            m = cls((H, W), theta_on=0.3, theta_off=0.3, seed=4, **(
                {"preset": "dvs346", "shot_noise_rate_hz": 50.0} if model == "voltmeter" else {}))
            it = iter(sp)
            b0 = next(it)
            m.start(0, sp.lum0)
            return Events.concat([m.process_tiles(b0)] + [m.process_tiles(b) for b in it] + [m.flush()])
        finally:
            numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)

    a = run(1, 7)
    b = run(2, 4096)
    assert len(a) > 100 and np.all(np.diff(a.t) >= 0)
    for f in ("t", "x", "y", "p"):
        assert np.array_equal(getattr(a, f), getattr(b, f))


def test_gsplat_renderer_adapter_drives_the_tile_sampler(monkeypatch):
    """The event stage's gsplat adapter (whole-image renders behind the tile
    renderer's interface) runs the tile sampler end to end. gsplat itself
    needs CUDA; the CPU rasterizer stands in for it here, so the samples must
    be the forward renderer's: same times, same values to rounding."""
    import torch

    from gs2e.events import rendered
    from gs2e.splat.rasterize import rasterize

    def stand_in(p, cam, bg, sh_degree, backend):
        assert backend == "gsplat"
        return rasterize(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], p["sh"],
                         cam, background=bg, sh_degree=sh_degree)

    monkeypatch.setattr(rendered, "render", stand_in)
    g = _textured(n=24)
    cpu = _renderer(g)
    adapter = rendered._GsplatRenderer({k: torch.tensor(v, dtype=torch.float32) for k, v in g.items()},
                                       {"sh_degree": 0}, cpu, (0.0, 0.0, 0.0))
    runs = []
    for r in (cpu, adapter):
        sp = TileSampler(r, _pan(0.3, 0.1), 0, 20_000, 0.15, 1e-3, dt_min_us=10, dt_max_us=8000,
                         dt_init_us=400, max_motion_px=2.0)
        runs.append(_collect(sp)[0])
    assert runs[0].keys() == runs[1].keys() and sum(len(s) for s in runs[0].values()) > len(runs[0])
    for k in runs[0]:
        assert [t for t, _ in runs[0][k]] == [t for t, _ in runs[1][k]]
        d = max(float(np.abs(a - b).max()) for (_, a), (_, b) in zip(runs[0][k], runs[1][k]))
        assert d < 1e-5, (k, d)  # float32 parameters in the adapter, float64 here: rounding


def test_frames_to_tile_batch_layout_on_sizes_off_the_tile_grid():
    """TileBatch.from_frames (one-pass copy into the tile layout) against the
    padded reshape it replaced: tile-major, frame-minor, zeros past the edge."""
    from gs2e.events.models import TILE, TileBatch

    rng = np.random.default_rng(0)
    for B, H, W in ((1, 1, 1), (3, 17, 33), (2, 32, 16), (5, 20, 47)):
        frames = rng.random((B, H, W)).astype(np.float32)
        ty, tx = -(-H // TILE), -(-W // TILE)
        pad = np.zeros((B, ty * TILE, tx * TILE), np.float32)
        pad[:, :H, :W] = frames
        want = pad.reshape(B, ty, TILE, tx, TILE).transpose(1, 3, 0, 2, 4).reshape(-1, TILE, TILE)
        ts = np.arange(B + 1, dtype=np.int64) * 100
        b = TileBatch.from_frames(ts, frames, key0=7)
        np.testing.assert_array_equal(b.lum, want)
        assert len(b.tiles) == ty * tx and b.lum.flags.c_contiguous
        np.testing.assert_array_equal(b.t0_us, np.tile(ts[:-1], ty * tx))
