"""The tangent pass (gs2e.splat.tangent, issue 67): a continuous render's exact
time derivative, in forward mode through projection and compositing."""

import numpy as np
import pytest

from gs2e.splat.forward import ContinuousRenderer, ForwardRenderer, OrderKnots
from splat_scenes import look_at_camera, random_scene


def _scene(sh_degree: int, n: int = 400, seed: int = 5, background=(0.0, 0.0, 0.0), scale_range=(-3.5, -1.5)):
    p = random_scene(n=n, seed=seed, sh_degree=sh_degree, scale_range=scale_range)
    cam = look_at_camera(40, 32)
    params = {k: v.detach().numpy() for k, v in p.items() if k != "background"}
    params = {"sh_dc": params["sh"][:, :1], "sh_rest": params["sh"][:, 1:], **params}
    del params["sh"]
    r = ForwardRenderer(params, sh_degree, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                        background=background, dtype=np.float64, window="smooth")
    c2w0 = np.linalg.inv(cam.viewmat)

    def pose(t_us):  # turning about the scene and sliding: Gaussians swap depth
        a = 0.5 * t_us / 1e6
        rot = np.array([[np.cos(a), 0, np.sin(a), 0.3 * t_us / 1e6], [0, 1, 0, 0],
                        [-np.sin(a), 0, np.cos(a), 0], [0, 0, 0, 1]])
        return rot @ c2w0

    return r, pose


def _central(cr, t, h=0.25):
    return (cr.render(t + h).copy() - cr.render(t - h).copy()) / (2 * h)


@pytest.mark.parametrize("sh_degree,background", [(0, (0.0, 0.0, 0.0)), (2, (0.2, 0.5, 0.9))])
def test_tangent_is_the_derivative_of_the_continuous_render(sh_degree, background):
    """Against a central difference of the float64 continuous render over
    +-0.25 us, outside a cross-fade and inside one (where ds/dt (B - A)
    enters): relative error under 1e-5, with view-dependent colours and a
    background (its T term); the image has the float64 render's bits (the
    same kernel, the derivative carried beside it), blended alike."""
    r, pose = _scene(sh_degree, background=background)
    knots = OrderKnots(0.0, 1e5, fade=0.25)
    cr = ContinuousRenderer(r, pose, knots, 1e6)
    crossfaded = False
    for t in (2.1e4, 5.03e4, 6.2e4, 8.0e4):  # before the fade, inside it twice, after it
        img, dimg = cr.render_tangent(t)
        ref = cr.render(t)
        if knots.bracket(t)[1] in (0.0, 1.0):
            np.testing.assert_array_equal(img, ref)
        else:  # blended in float64 here, in the kernel there
            np.testing.assert_allclose(img, ref, rtol=0, atol=1e-14)
        fd = _central(cr, t)
        scale = np.abs(fd).max()
        assert scale > 1e-7  # the image moves
        assert np.abs(dimg - fd).max() < 1e-5 * scale, (t, np.abs(dimg - fd).max() / scale)
        j, w = knots.bracket(t)
        if w not in (0.0, 1.0):  # the fade's own term, ds/dt (B - A), counts here
            r.render_blended(pose(t), cr._order(j), cr._order(j), 0.0)
            a = r.image.copy()
            r.render_blended(pose(t), cr._order(j + 1), cr._order(j + 1), 0.0)
            crossfaded |= knots.weight_rate(t) * np.abs(r.image - a).max() > 0.05 * scale
    assert crossfaded


def test_tangent_through_opaque_stacks_where_pixels_stop():
    """Many large opaque Gaussians: pixels stop compositing (T under T_MIN)
    with their last weights faded (r(T), r'(T) active); the derivative still
    matches the central difference."""
    r, pose = _scene(0, n=300, seed=11, scale_range=(-1.2, -0.6))
    cr = ContinuousRenderer(r, pose, OrderKnots(0.0, 1e5, fade=0.25), 1e6)
    t = 3.3e4
    r.render(pose(t))
    assert (r._T < 2e-4).mean() > 0.2  # many pixels stopped, or near it
    img, dimg = cr.render_tangent(t)
    fd = _central(cr, t)
    assert np.abs(dimg - fd).max() < 1e-5 * np.abs(fd).max()


def test_weight_rate_is_the_derivative_of_the_fade():
    k = OrderKnots(100.0, 1000.0, fade=0.25)
    for t in (200.0, 480.0, 600.0, 700.0, 1500.0):
        fd = (k.bracket(t + 0.01)[1] - k.bracket(t - 0.01)[1]) / 0.02
        assert k.weight_rate(t) == pytest.approx(fd, abs=1e-6)
    assert k.weight_rate(200.0) == 0.0 and k.weight_rate(600.0) == pytest.approx(1.5 / 250.0)


def test_tangent_refuses_the_cut_window_and_a_path_without_a_rate():
    r, pose = _scene(0)
    cr = ContinuousRenderer(r, pose, OrderKnots(0.0, 1e5), 0.0)  # a path of one instant
    with pytest.raises(ValueError, match="no pose rate at 0.0 us"):
        cr.render_tangent(0.0)
    cut = ForwardRenderer({"sh_dc": np.zeros((1, 1, 3)), "sh_rest": np.zeros((1, 0, 3)),
                           "means": np.zeros((1, 3)), "quats": np.array([[1.0, 0, 0, 0]]),
                           "log_scales": np.zeros((1, 3)), "opacity_logits": np.zeros(1)},
                          0, 30.0, 30.0, 8.0, 8.0, 16, 16)
    order = np.zeros(1, np.int64)
    with pytest.raises(ValueError, match="cut window jumps in time"):
        cut.render_tangent(np.eye(4), np.zeros((4, 4)), order, order, 0.0, 0.0)
