"""The smooth compositing window and the continuous renderer (issue 67)."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import torch

from gs2e.splat import raster as R
from gs2e.splat.forward import ORDER_FADE, ContinuousRenderer, ForwardRenderer, OrderKnots, order_knots
from gs2e.splat.project import LOWPASS_PX2
from gs2e.splat.rasterize import SplatCamera, rasterize
from gs2e.splat.reference import render_reference
from splat_scenes import compare, look_at_camera, random_scene


def test_smooth_window_matches_the_dense_reference_and_its_gradients():
    p = random_scene(n=80, seed=3)
    _, errs, _ = compare(p, look_at_camera(32, 24), 1e-7, window="smooth")
    assert errs["image"] < 1e-12


def test_smooth_window_fades_the_weights_before_a_pixel_stops():
    """Opaque layers take transmittance below T_MIN: the ramp and the applied
    stopping Gaussian, against the reference (values and gradients)."""
    rng = np.random.default_rng(0)
    n = 40
    p = {"means": np.c_[rng.uniform(-0.3, 0.3, (n, 2)), np.linspace(-0.5, 0.5, n)],
         "quats": np.tile([1.0, 0, 0, 0], (n, 1)) + rng.normal(0, 0.1, (n, 4)),
         "log_scales": np.log(rng.uniform(0.2, 0.6, (n, 3))), "opacity_logits": rng.uniform(0.5, 3.0, n),
         "sh": rng.normal(0, 0.5, (n, 1, 3)), "background": np.array([0.2, 0.4, 0.1])}
    p = {k: torch.tensor(v, dtype=torch.float64, requires_grad=True) for k, v in p.items()}
    cam = look_at_camera(24, 20)
    # 1e-4: depth = accumulated depth / alpha, and where only a Gaussian's tail
    # reaches a pixel its alpha (o e^p less the tangent at the cut) is a
    # difference of nearly equal terms, which the two round differently; the
    # image's and alpha's gradients alone agree to 1e-14 here
    fast, errs, _ = compare(p, cam, 1e-4, window="smooth")
    assert errs["image"] < 1e-12 and errs["d_opacity_logits"] < 1e-7
    T = 1.0 - fast[1].detach().numpy()
    assert (T < R.T_MIN).mean() > 0.05  # a tenth of the pixels stop


def _one_gaussian(u_px: float, opacity: float, cam: SplatCamera, window: str) -> float:
    """Pixel (8, 8)'s red value with one Gaussian of 1 px sigma whose centre
    lies ``u_px`` px right of the pixel centre (the camera looks along +z
    from the origin)."""
    z = 3.0
    x = (8.5 + u_px - cam.cx) * z / cam.fx
    y = (8.5 - cam.cy) * z / cam.fy
    s = np.sqrt(1.0 - LOWPASS_PX2) * z / cam.fx  # with the low-pass: sigma 1 px on screen
    t = {"means": [[x, y, z]], "quats": [[1.0, 0, 0, 0]], "log_scales": [[np.log(s)] * 3],
         "opacity_logits": [float(np.log(opacity / (1 - opacity)))], "sh": [[[1.0, 1.0, 1.0]]]}
    t = {k: torch.tensor(v, dtype=torch.float64) for k, v in t.items()}
    img = rasterize(t["means"], t["quats"], t["log_scales"], t["opacity_logits"], t["sh"], cam,
                    window=window)[0]
    return float(img[8, 8, 0])


@pytest.mark.parametrize("opacity", [0.9, 0.01])  # cut at 3 sigma; cut at alpha 1/255
def test_a_gaussian_edge_crossing_a_pixel_jumps_only_with_the_cut_window(opacity):
    cam = SplatCamera(np.eye(4), 40.0, 40.0, 8.0, 8.0, 16, 16)
    us = np.linspace(1.0, 4.0, 3001)  # the centre moves 3 px, 1 mpx per step
    for window, jumps in (("cut", True), ("smooth", False)):
        v = np.array([_one_gaussian(u, opacity, cam, window) for u in us])
        step = np.abs(np.diff(v)).max()
        assert v[0] > 0.01 * opacity and v[-1] == 0.0
        assert (step > 1e-3 * opacity) == jumps, (window, step)
        if not jumps:  # C1: the slope, too, goes to 0 where the value does
            last = np.flatnonzero(v > 0)[-1]
            assert v[last] < 1e-5 * opacity


def test_continuous_renderer_cross_fades_a_depth_swap_and_equals_a_render_at_knots():
    """Two overlapping Gaussians that swap depth as the camera slides: the
    per-pose sort changes the pixel by a jump, the order held at knots and
    cross-faded does not; at a knot the continuous render is the render."""
    params = {"means": np.array([[-0.05, 0.0, 3.0], [0.05, 0.0, 3.0]]),
              "quats": np.tile([1.0, 0, 0, 0], (2, 1)),
              "log_scales": np.log(np.array([[0.3, 0.3, 0.01], [0.3, 0.3, 0.01]])),
              "opacity_logits": np.array([3.0, 3.0]),
              "sh": np.array([[[1.5, -1.5, -1.5]], [[-1.5, -1.5, 1.5]]])}
    params = {"sh_dc": params.pop("sh"), "sh_rest": np.zeros((2, 0, 3)), **params}
    r = ForwardRenderer(params, 0, 40.0, 40.0, 8.0, 8.0, 16, 16, dtype=np.float64, window="smooth")

    def pose(t_us):  # slides along x, turned a little: the two depths cross at t = 0.5 s
        c2w = np.eye(4)
        c2w[0, 3] = -0.2 + 0.4 * t_us / 1e6
        a = 0.2 * (t_us / 1e6 - 0.5)
        c2w[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        return c2w

    ts = np.linspace(0.4e6, 0.6e6, 401)
    plain = np.array([r.render(pose(t))[8, 8].copy() for t in ts])
    knots = OrderKnots(0.0, 0.07e6)  # the swap (0.5 s) between knots
    cr = ContinuousRenderer(r, pose, knots, 1e6)
    cont = np.array([cr.render(t)[8, 8].copy() for t in ts])
    jump = np.abs(np.diff(plain, axis=0)).max()
    assert jump > 0.05  # the swap: one jump
    # spread over the fade (ORDER_FADE of 70 ms, steps of 0.5 ms): the smoothstep's
    # steepest slope, 1.5 / (steps in the fade) of the jump per step
    steps = ORDER_FADE * 0.07e6 / 0.5e3
    assert np.abs(np.diff(cont, axis=0)).max() < 1.2 * 1.5 / steps * jump
    for t in (0.42e6, 0.49e6, 0.56e6):  # knots
        np.testing.assert_array_equal(cr.render(t), r.render(pose(t)))
    assert order_knots(r, pose, 0.0, 1e6, 2.0).dt_us > 0


def test_orders_cross_fade_over_the_middle_of_each_knot_interval():
    """OrderKnots.bracket: the weight of order j + 1 is 0 before the interval's
    middle ``fade``, 1 after it and a smoothstep across it (C1); fade 1 is the
    smoothstep over the whole interval."""
    k = OrderKnots(100.0, 1000.0, fade=0.25)
    assert k.bracket(100.0) == (0, 0.0) and k.bracket(474.0) == (0, 0.0)
    assert k.bracket(600.0) == (0, pytest.approx(0.5)) and k.bracket(726.0) == (0, 1.0)
    assert k.bracket(1099.0) == (0, 1.0) and k.bracket(1100.0) == (1, 0.0)
    t = np.linspace(100.0, 3100.0, 30001)
    w = np.array([sum(k.bracket(x)) for x in t])  # j + s: continuous and rising
    assert np.all(np.diff(w) >= 0) and np.abs(np.diff(w)).max() < 1e-3
    whole = OrderKnots(0.0, 1000.0, fade=1.0)
    for f in (0.0, 0.1, 0.5, 0.9):
        assert whole.bracket(1000.0 * f)[1] == pytest.approx(f * f * (3 - 2 * f))


def test_outside_the_fade_one_order_is_composited():
    """Where the weight is 0 or 1 the continuous render is the plain composite
    in one held order (no tile composited twice); inside the fade, two."""
    p = random_scene(n=300, seed=3, sh_degree=0)
    cam = look_at_camera(40, 32)
    params = {k: v.detach().numpy() for k, v in p.items() if k != "background"}
    r = ForwardRenderer(params, 0, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                        dtype=np.float64, window="smooth")
    c2w0 = np.linalg.inv(cam.viewmat)

    def pose(t_us):  # turning about the scene: Gaussians swap depth
        a = 0.5 * t_us / 1e6
        rot = np.array([[np.cos(a), 0, np.sin(a), 0], [0, 1, 0, 0], [-np.sin(a), 0, np.cos(a), 0], [0, 0, 0, 1]])
        return rot @ c2w0

    cr = ContinuousRenderer(r, pose, OrderKnots(0.0, 1e5, fade=0.25), 1e6)
    for t, j in ((2e4, 0), (9e4, 1), (1.2e5, 1)):  # before, after, next interval's start
        r.tiles_blended = 0
        img = cr.render(t).copy()
        order = r.depth_order_at(pose(j * 1e5))
        np.testing.assert_array_equal(img, r.render_blended(pose(t), order, order, 0.0))
        assert r.tiles_blended == 0
    cr.render(5e4)  # the middle of the fade
    assert r.tiles_blended > 0


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_render_blended_in_one_pass_is_two_renders_blended(dtype):
    """The cross-fade composites both orders in one pass, sharing a Gaussian's
    alphas where both lists hold it at the same position: the same bits as
    the image in each order alone, blended as (1 - s) a + s b."""
    p = random_scene(n=400, seed=7, sh_degree=1)
    cam = look_at_camera(48, 40)
    params = {k: v.detach().numpy() for k, v in p.items() if k != "background"}
    params = {"sh_dc": params["sh"][:, :1], "sh_rest": params["sh"][:, 1:], **params}
    del params["sh"]
    r = ForwardRenderer(params, 1, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                        background=(0.1, 0.2, 0.3), dtype=dtype, window="smooth")
    c2w = np.linalg.inv(cam.viewmat)
    side = np.linalg.inv(look_at_camera(48, 40, eye=(2.0, 0.5, -3.5)).viewmat)
    shuffled = np.random.default_rng(0).permutation(r.n_gaussians)  # nearly no position shared
    a = r.depth_order_at(c2w)
    for b in (r.depth_order_at(side), shuffled):  # another pose's order: shared and swapped
        img_a = r.render_blended(c2w, a, a, 0.0).copy()
        img_b = r.render_blended(c2w, b, b, 0.0).copy()
        assert np.abs(img_a - img_b).max() > 1e-3  # the orders differ on the image
        for s in (0.25, 1.0):
            r.tiles_blended = 0
            got = r.render_blended(c2w, a, b, s)
            np.testing.assert_array_equal(got, img_a + dtype(s) * (img_b - img_a))
            assert r.tiles_blended > 0
    np.testing.assert_array_equal(r.render_blended(c2w, a, a, 0.5), r.render(c2w))
    both = r.render_blended(c2w, a, shuffled, 0.5).copy()
    threads = numba.get_num_threads()
    try:  # tiles split over one thread instead of several: the same bits
        numba.set_num_threads(1)
        np.testing.assert_array_equal(r.render_blended(c2w, a, shuffled, 0.5), both)
    finally:
        numba.set_num_threads(threads)


def test_windows_are_checked():
    cam = look_at_camera(8, 8)
    p = random_scene(n=3, seed=0)
    with pytest.raises(Exception, match="window"):
        rasterize(*(p[k] for k in ("means", "quats", "log_scales", "opacity_logits", "sh")), cam,
                  window="soft")
    with pytest.raises(ValueError, match="window"):
        R.forward_kernel(np.float32, np.zeros(2, np.int64), "soft")
    with pytest.raises(Exception, match="gsplat"):
        rasterize(*(p[k] for k in ("means", "quats", "log_scales", "opacity_logits", "sh")), cam,
                  backend="gsplat", window="smooth")


def test_float32_smooth_forward_is_float64_to_rounding():
    p = random_scene(n=80, seed=4, dtype=torch.float32)
    cam = look_at_camera(32, 24)
    keys = ("means", "quats", "log_scales", "opacity_logits", "sh")
    with torch.no_grad():
        a = rasterize(*(p[k] for k in keys), cam, p["background"], window="smooth")[0]
    b = render_reference(*(p[k].detach().double().requires_grad_() for k in keys), cam,
                         p["background"].detach().double(), window="smooth")[0]
    assert float((a.double() - b.detach()).abs().max()) < 1e-5


def test_config_refuses_the_smooth_window_on_gsplat():
    from gs2e.common.errors import ConfigError
    from gs2e.config import check_config, load_config

    with pytest.raises(ConfigError, match="splat.window"):
        check_config(load_config({"splat": {"window": "smooth", "backend": "gsplat"}}))
    with pytest.raises(ConfigError, match="render.backend"):
        check_config(load_config({"splat": {"window": "smooth"}, "render": {"backend": "gsplat"}}),
                     workflow=True)
    check_config(load_config({"splat": {"window": "smooth", "backend": "auto"}}), workflow=True)
    # the default window is smooth: asking for gsplat alone says what to set
    with pytest.raises(ConfigError, match="splat.window: smooth .*set splat.window: cut"):
        check_config(load_config({"splat": {"backend": "gsplat"}}))


def test_backend_for_a_smooth_model_is_the_cpu():
    from gs2e.common.errors import ConfigError
    from gs2e.splat.backend import resolve_backend_for

    assert resolve_backend_for("auto", "smooth", "render.backend") == "cpu"
    assert resolve_backend_for("cpu", "smooth") == "cpu"
    with pytest.raises(ConfigError, match="render.backend"):
        resolve_backend_for("gsplat", "smooth", "render.backend")
