"""Forward-only renderer (gs2e.splat.forward): exact against the training
rasterizer, tile renders exact against whole renders, candidates complete."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gs2e.splat.forward import ForwardRenderer
from gs2e.splat.rasterize import rasterize
from splat_scenes import look_at_camera, random_scene


def _orbit(angle_deg: float, radius: float = 4.0, height: float = 0.0) -> np.ndarray:
    a = np.deg2rad(angle_deg)
    eye = np.array([radius * np.sin(a), height, -radius * np.cos(a)])
    return np.linalg.inv(look_at_camera(eye=eye).viewmat)


def _scene(n=400, seed=0, sh_degree=3, dtype=torch.float32, **kw):
    p = random_scene(n=n, seed=seed, dtype=dtype, sh_degree=sh_degree, **kw)
    params = {"means": p["means"], "quats": p["quats"], "log_scales": p["log_scales"],
              "opacity_logits": p["opacity_logits"], "sh_dc": p["sh"][:, :1], "sh_rest": p["sh"][:, 1:]}
    return p, params


@pytest.mark.parametrize("sh_degree", [0, 3])
@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_whole_render_equals_training_rasterizer(sh_degree, dtype):
    p, params = _scene(sh_degree=sh_degree, dtype=dtype)
    cam = look_at_camera(width=80, height=56)
    c2w = np.linalg.inv(cam.viewmat)
    with torch.no_grad():
        img = rasterize(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], p["sh"], cam,
                        background=p["background"], sh_degree=sh_degree)[0].numpy()
    fr = ForwardRenderer(params, sh_degree, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                         background=p["background"].detach().numpy(),
                         dtype=np.float32 if dtype == torch.float32 else np.float64)
    out = fr.render(c2w)
    np.testing.assert_array_equal(out, img)


def test_whole_renders_along_a_path_equal_fresh_renders():
    """Each whole render starts its depth order from the last one's
    (:func:`gs2e.splat.raster.resort_by_depth`): along small steps, a jump
    of 120 degrees (too many moves: sorted from scratch), Gaussians leaving
    and entering the view, and back, every image equals that of a renderer
    with no history, bit for bit."""
    p, params = _scene(n=600, sh_degree=0)
    cam = look_at_camera(width=72, height=48)
    bg = p["background"].detach().numpy()

    def renderer():
        return ForwardRenderer(params, 0, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                               background=bg)

    walk = renderer()
    for angle in [0.0, 0.05, 0.1, 3.0, 123.0, 123.5, 40.0, 40.01, 0.0]:
        c2w = _orbit(angle)
        np.testing.assert_array_equal(walk.render(c2w).copy(), renderer().render(c2w))


def test_resort_by_depth_equals_a_stable_argsort():
    """Ties of depth (a tenth of the values repeated) broken by index, any
    previous order (shuffled, with members no longer visible), and the
    move budget reported when it runs out."""
    from gs2e.splat.raster import resort_by_depth

    rng = np.random.default_rng(5)
    n = 500
    depths = rng.random(n)
    depths[rng.integers(0, n, 50)] = depths[0]
    visible = rng.random(n) < 0.8
    want = np.flatnonzero(visible)[np.argsort(depths[visible], kind="stable")]
    for prev in (np.zeros(0, np.int64), rng.permutation(n)[:300], want.copy(), want[::-1].copy()):
        got, ok = resort_by_depth(prev.astype(np.int64), visible, depths, n * n)
        assert ok
        np.testing.assert_array_equal(got, want)
    assert not resort_by_depth(want[::-1].copy(), visible, depths, n)[1]


@pytest.mark.parametrize("sh_degree", [0, 2])
def test_tile_renders_equal_whole_renders_over_a_span(sh_degree):
    """Candidates built from a few poses of an orbit arc cover every pose in
    between: each tile rendered alone equals the whole render, bit for bit."""
    p, params = _scene(n=600, seed=3, sh_degree=sh_degree)
    cam = look_at_camera(width=96, height=64)
    fr = ForwardRenderer(params, sh_degree, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                         background=(0.1, 0.2, 0.3))
    ref = ForwardRenderer(params, sh_degree, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                          background=(0.1, 0.2, 0.3))
    span = [_orbit(a) for a in (0.0, 1.0, 2.0)]
    cand = fr.candidates(span, margin_px=1.0)
    rng = np.random.default_rng(0)
    for a in (0.0, 0.37, 1.0, 1.61, 2.0):
        whole = ref.render(_orbit(a)).copy()
        tiles = np.sort(rng.choice(fr.n_tiles, size=7, replace=False))
        img = fr.render_tiles(_orbit(a), tiles, cand)
        for t in tiles:
            ty, tx = divmod(int(t), fr.tiles_x)
            sl = np.s_[ty * 16:(ty + 1) * 16, tx * 16:(tx + 1) * 16]
            np.testing.assert_array_equal(img[sl], whole[sl])
    assert fr.gaussians_projected < 5 * 600 + 3 * 600  # subsets, not every Gaussian per call


def test_tile_renders_stay_exact_when_gaussians_enter_the_view():
    """A fast pan brings Gaussians in from outside the image between the
    candidate poses (and one crosses the near plane): tile renders still
    equal whole renders everywhere in between."""
    p, params = _scene(n=800, seed=5, sh_degree=1, extent=3.0)
    cam = look_at_camera(width=64, height=48)
    fr = ForwardRenderer(params, 1, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    ref = ForwardRenderer(params, 1, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    span = [_orbit(a, radius=2.0) for a in (10.0, 12.0, 14.0)]
    cand = fr.candidates(span, margin_px=1.0)
    assert cand.max_step_px > 0
    tiles = np.arange(fr.n_tiles)
    for a in np.linspace(10.0, 14.0, 9):
        np.testing.assert_array_equal(fr.render_tiles(_orbit(a, radius=2.0), tiles, cand),
                                      ref.render(_orbit(a, radius=2.0)))


def test_candidates_of_a_static_span_are_exact_and_empty_tiles_stay_background():
    p, params = _scene(n=20, seed=1, sh_degree=0, extent=0.8, scale_range=(-4.5, -4.0))
    cam = look_at_camera(width=128, height=96)
    c2w = np.linalg.inv(cam.viewmat)
    fr = ForwardRenderer(params, 0, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                         background=(0.25, 0.5, 0.75))
    cand = fr.candidates([c2w, c2w], margin_px=0.0)
    assert np.all(cand.speed_px == 0.0)
    empty = np.flatnonzero(np.diff(cand.offsets) == 0)
    assert len(empty) > 0
    whole = fr.render(c2w).copy()
    for t in empty:
        ty, tx = divmod(int(t), fr.tiles_x)
        block = whole[ty * 16:(ty + 1) * 16, tx * 16:(tx + 1) * 16]
        np.testing.assert_array_equal(block, np.broadcast_to(np.float32([0.25, 0.5, 0.75]), block.shape))


def test_tile_lists_do_not_depend_on_candidate_order():
    """Per-tile lists are sorted by insertion from the candidates' order (depth
    at the window's middle pose): reversed or shuffled candidates, and equal
    depths (ties by index), give the same images, bit for bit."""
    from dataclasses import replace

    p, params = _scene(n=500, seed=7, sh_degree=0)
    with torch.no_grad():  # a block of exact depth ties
        params["means"][:40, 2] = params["means"][0, 2]
    cam = look_at_camera(width=80, height=64)
    fr = ForwardRenderer(params, 0, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    span = [_orbit(a) for a in (0.0, 20.0, 40.0)]  # wide: order at 20 deg is far from 0 and 40
    cand = fr.candidates(span, margin_px=1.0)
    rng = np.random.default_rng(1)
    shuffled, backwards = cand.gids.copy(), cand.gids.copy()
    for t in range(fr.n_tiles):
        a, b = cand.offsets[t], cand.offsets[t + 1]
        shuffled[a:b] = rng.permutation(shuffled[a:b])
        backwards[a:b] = backwards[a:b][::-1]
    tiles = np.arange(fr.n_tiles)
    for a in (0.0, 13.0, 40.0):
        ref = fr.render_tiles(_orbit(a), tiles, cand).copy()
        for gids in (shuffled, backwards):
            np.testing.assert_array_equal(
                fr.render_tiles(_orbit(a), tiles, replace(cand, gids=gids)), ref)
        np.testing.assert_array_equal(ref, fr.render(_orbit(a)))
