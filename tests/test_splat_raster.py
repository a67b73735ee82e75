"""Fast rasterizer against the dense torch reference, finite differences,
determinism."""

import numpy as np
import pytest
import torch

from splat_scenes import KEYS, _loss, _render, compare, look_at_camera, random_scene, rel_err
from gs2e.splat import raster as R
from gs2e.splat.rasterize import rasterize


@pytest.mark.parametrize("seed,degree", [(0, 3), (1, 0), (2, 1)])
def test_matches_reference_float64(seed, degree):
    p = random_scene(300, seed=seed, sh_degree=degree)
    cam = look_at_camera(eye=(0.2 * seed, -0.3, -4.0))
    fast, _, _ = compare(p, cam, 1e-4)
    assert float(fast[1].detach().max()) > 0.9 and int((fast[3]["radii"] > 0).sum()) > 100  # non-trivial


def test_matches_reference_float32():
    p = random_scene(300, seed=5, dtype=torch.float32)
    fast, _, _ = compare(p, look_at_camera(), 1e-3)
    assert fast[0].dtype == torch.float32


def test_active_degree_below_stored():
    p = random_scene(200, seed=7, sh_degree=3)
    compare(p, look_at_camera(), 1e-4, sh_degree=1)


def test_early_termination_and_alpha_clamp_exercised():
    """Dense opaque scene: many pixels stop at T < 1e-4 and alphas hit 0.99;
    whole 8-pixel blocks stop, which both kernels then skip."""
    p = random_scene(300, seed=11, extent=0.6, scale_range=(-2.5, -1.5))
    with torch.no_grad():
        p["opacity_logits"].fill_(6.0)
    fast, _, _ = compare(p, look_at_camera(), 1e-4)
    T = 1 - fast[1].detach()
    assert float(T.min()) >= 1e-4 - 1e-12  # never composited below the stop threshold
    assert float((T < 1e-3).float().mean()) > 0.1  # ... but many pixels got there
    W = T.shape[1] // R.LANES * R.LANES
    blocks = (T[:, :W] < 1e-3).reshape(T.shape[0], -1, R.LANES).all(dim=2)
    assert int(blocks.sum()) >= 10  # blocks (tile-aligned: 16 = 2 x 8) with every pixel near stop


def test_gradients_match_finite_differences():
    p = random_scene(6, seed=4, extent=0.5, scale_range=(-1.6, -1.0))
    cam = look_at_camera(width=14, height=11, fx=12.0)
    params = [p[k] for k in (*KEYS, "background")]

    def f():
        with torch.no_grad():
            return float(_loss(_render(rasterize, p, cam), seed=3))

    grads = torch.autograd.grad(_loss(_render(rasterize, p, cam), seed=3), params)
    eps = 1e-6
    for x, g in zip(params, grads):
        flat = x.data.view(-1)
        num = torch.empty_like(flat)
        for i in range(flat.numel()):
            old = float(flat[i])
            flat[i] = old + eps
            fp = f()
            flat[i] = old - eps
            fm = f()
            flat[i] = old
            num[i] = (fp - fm) / (2 * eps)
        assert float(num.abs().max()) > 1e-3  # the scene is not trivially flat
        assert rel_err(g.view(-1), num) < 1e-5, (x.shape, g.view(-1), num)


def test_deterministic_and_tile_independent():
    p = random_scene(300, seed=8, dtype=torch.float32)
    cam = look_at_camera()
    outs = []
    for _ in range(2):
        img, alpha, depth, meta = _render(rasterize, p, cam)
        g = torch.autograd.grad(_loss((img, alpha, depth, meta)), [p[k] for k in KEYS])
        outs.append([img, alpha, depth, *g, meta["grad2d"]])
    for a, b in zip(*outs):
        assert torch.equal(a, b)  # bit-identical
    # same per-pixel depth order whatever the tile size -> identical forward
    m2 = meta["means2d"].numpy()
    args = (m2.astype(np.float32), meta["conics"].numpy().astype(np.float32),
            torch.sigmoid(p["opacity_logits"]).detach().numpy(),
            np.ones((300, 2), np.float32), np.zeros(2, np.float32), cam.width, cam.height)
    res = []
    for tile in (8, 16, 32):
        off, gids = R.bin_gaussians(m2, meta["depths"].numpy(), meta["radii"].numpy(),
                                    cam.width, cam.height, tile)
        res.append(R.rasterize_forward(*args, off, gids, tile)[1])
        if tile == 16:
            n16 = len(gids)
    # opacity-aware boxes: fewer tile pairs, same image
    off, gids = R.bin_gaussians(m2, meta["depths"].numpy(), meta["radii"].numpy(),
                                cam.width, cam.height, 16, args[2])
    assert len(gids) == meta["n_pairs"] < n16
    res.append(R.rasterize_forward(*args, off, gids, 16)[1])
    for r in res[1:]:
        assert np.array_equal(res[0], r)


def test_empty_scene_gives_background():
    p = random_scene(5, seed=1)
    with torch.no_grad():
        p["means"][:, 2] = -50.0  # all behind the camera
    img, alpha, depth, meta = _render(rasterize, p, look_at_camera())
    assert torch.allclose(img, p["background"].detach().expand_as(img))
    assert float(alpha.detach().abs().max()) == 0.0 and float(depth.detach().abs().max()) == 0.0
    assert meta["n_pairs"] == 0
    g = torch.autograd.grad(img.sum(), [p["means"], p["background"]])
    assert float(g[0].abs().max()) == 0.0
    assert torch.allclose(g[1], torch.full((3,), 64.0 * 48, dtype=torch.float64))


def test_same_bits_whatever_the_thread_count():
    import numba
    p = random_scene(300, seed=12, dtype=torch.float32)
    cam = look_at_camera()
    res = []
    n0 = numba.get_num_threads()
    try:
        for nt in sorted({1, n0}):
            numba.set_num_threads(nt)
            out = _render(rasterize, p, cam)
            res.append([*out[:3], *torch.autograd.grad(_loss(out), [p[k] for k in KEYS])])
    finally:
        numba.set_num_threads(n0)
    for a, b in zip(res[0], res[-1]):
        assert torch.equal(a, b)


def test_fixed_background_gets_no_gradient_and_changes_nothing_else():
    """A background that does not require grad (training) skips its gradient;
    every other gradient keeps its bits."""
    p = random_scene(200, seed=13)
    cam = look_at_camera()
    res = []
    for bg_grad in (True, False):
        p["background"].requires_grad_(bg_grad)
        out = _render(rasterize, p, cam)
        res.append(torch.autograd.grad(_loss(out), [p[k] for k in KEYS]))
    p["background"].requires_grad_(True)
    for a, b in zip(*res):
        assert torch.equal(a, b)


def test_tile_schedule_splits_by_work():
    """Every tile exactly once, each worker's tiles ascending, and the
    longest-first bound: loads differ by at most the largest tile cost."""
    rng = np.random.default_rng(3)
    counts = np.concatenate([rng.integers(0, 400, 150), np.zeros(40, np.int64),
                             rng.integers(0, 20, 146)])  # busy top, empty band, sparse rest
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    for n_workers in (1, 2, 3, 7, 400):
        order, bounds = R.tile_schedule(offsets, n_workers)
        assert bounds.shape == (n_workers + 1,) and bounds[0] == 0 and bounds[-1] == len(counts)
        assert np.array_equal(np.sort(order), np.arange(len(counts)))
        cost = counts + 16.0
        loads = [cost[order[a:b]].sum() for a, b in zip(bounds[:-1], bounds[1:])]
        for a, b in zip(bounds[:-1], bounds[1:]):
            assert np.all(np.diff(order[a:b]) > 0)
        assert max(loads) - min(loads) <= cost.max()
        again = R.tile_schedule(offsets, n_workers)
        assert np.array_equal(order, again[0]) and np.array_equal(bounds, again[1])
    # a contiguous half split would give the busy top to one thread
    order, bounds = R.tile_schedule(offsets, 2)
    loads = [(counts[order[a:b]] + 16.0).sum() for a, b in zip(bounds[:-1], bounds[1:])]
    halves = [(counts[:168] + 16.0).sum(), (counts[168:] + 16.0).sum()]
    assert max(loads) / min(loads) < 1.01 < max(halves) / min(halves)


def test_kernels_give_same_bits_for_any_split_of_tiles():
    """The forward and backward kernels take the tile split as input; a tile's
    pixels and pair rows do not depend on which worker or order renders it."""
    p = random_scene(300, seed=12, dtype=torch.float32)
    cam = look_at_camera()
    meta = _render(rasterize, p, cam)[3]
    m2 = meta["means2d"].numpy().astype(np.float32)
    cn = meta["conics"].numpy().astype(np.float32)
    op = torch.sigmoid(p["opacity_logits"]).detach().numpy()
    feats = np.random.default_rng(0).random((300, 4)).astype(np.float32)
    W, H = cam.width, cam.height
    off, gids = R.bin_gaussians(meta["means2d"].numpy(), meta["depths"].numpy(),
                                meta["radii"].numpy(), W, H, 16, op)
    n_tiles = len(off) - 1
    g_out = np.random.default_rng(1).random((H, W, 4))
    g_T = np.random.default_rng(2).random((H, W))
    res = []
    for sched in (R.tile_schedule(off, 1), R.tile_schedule(off, 3), R.tile_schedule(off, 64),
                  (np.arange(n_tiles)[::-1].copy(), np.array([0, n_tiles]))):
        out = np.empty((H, W, 4), np.float32)
        T = np.empty((H, W), np.float32)
        nc = np.empty((H, W), np.int32)
        R.raster_forward_kernel(np.arange(n_tiles), off, gids, m2, cn, op, feats,
                                np.zeros(4, np.float32), W, H, 16, out, T, nc, *sched)
        pair = np.empty((len(gids), 10))
        R.raster_backward_kernel(off, gids, m2, cn, op, feats, W, H, 16, T, nc, g_out, g_T,
                                 pair, *sched)
        res.append((out, T, nc, pair))
    assert float(res[0][1].min()) < 0.5  # Gaussians cover part of the image
    for r in res[1:]:
        for a, b in zip(res[0], r):
            assert np.array_equal(a, b)


def test_no_gaussians():
    p = random_scene(0, seed=0)
    img, alpha, depth, meta = _render(rasterize, p, look_at_camera())
    assert torch.equal(img, p["background"].detach().expand_as(img))
    g = torch.autograd.grad(img.sum(), [p["means"], p["sh"]])
    assert g[0].shape == (0, 3) and g[1].shape == (0, 16, 3)



def test_bin_kernel_same_lists_for_any_number_of_workers():
    """Tile lists built by bands of tile rows in parallel: each tile's list in
    the given order, as a plain loop builds it, whatever the worker count."""
    rng = np.random.default_rng(3)
    n, W, H, tile = 3000, 203, 117, 16
    means2d = np.column_stack([rng.uniform(-30, W + 30, n), rng.uniform(-30, H + 30, n)])
    radii = rng.uniform(0.0, 40.0, n)
    radii[::7] = 0.0  # culled
    order = rng.permutation(n).astype(np.int64)
    tiles_x, tiles_y = -(-W // tile), -(-H // tile)
    ref = [[] for _ in range(tiles_x * tiles_y)]
    for g in order:
        if radii[g] <= 0:
            continue
        x0, x1, y0, y1 = R._tile_rect(means2d[g, 0], means2d[g, 1], radii[g], W, H, tile,
                                      tiles_x, tiles_y)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                ref[ty * tiles_x + tx].append(g)
    for n_workers in (1, 2, 3, 5, 64):
        offsets, gids = R.bin_kernel(order, means2d, radii, W, H, tile, n_workers)
        assert [gids[offsets[t]:offsets[t + 1]].tolist() for t in range(len(ref))] == ref
