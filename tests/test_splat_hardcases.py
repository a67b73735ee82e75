"""Numerically hard cases: each must stay finite and match the dense reference."""

import numpy as np
import pytest
import torch

from splat_scenes import KEYS, _render, compare, look_at_camera, random_scene, rel_err
from gs2e.common.so3 import rotmat_to_quat
from gs2e.splat.rasterize import NonFiniteError, SplatCamera, rasterize


def _scene(n=120, seed=0, **kw):
    return random_scene(n, seed=seed, extent=1.0, **kw)


def _set(p, key, rows, value):
    with torch.no_grad():
        p[key][rows] = torch.as_tensor(value, dtype=p[key].dtype)


def test_near_singular_2d_covariance():
    """Flat discs seen exactly edge-on: the 3D covariance projects to a line,
    only the 0.3 px^2 low-pass keeps the 2D covariance invertible."""
    p = _scene(seed=1)
    cam = look_at_camera()  # looks along +z
    rows = slice(0, 40)
    # disc normal (local z) perpendicular to the viewing ray of each centre
    eye = cam.campos()
    m = p["means"].detach().numpy()[rows]
    ray = (m - eye) / np.linalg.norm(m - eye, axis=1, keepdims=True)
    n = np.cross(ray, [0.0, 1.0, 0.0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    a = np.cross(n, ray)
    Rm = np.stack([ray, a, n], axis=2)  # columns: local x, y, z in world
    _set(p, "quats", rows, rotmat_to_quat(Rm))
    _set(p, "log_scales", rows, [0.5, 0.5, -16.0])
    fast, _, _ = compare(p, cam, 1e-4)
    con = fast[3]["conics"][:40][fast[3]["radii"][:40] > 0]
    assert len(con) > 10
    det2 = 1.0 / (con[:, 0] * con[:, 2] - con[:, 1] ** 2)  # det of the 2D covariance
    trace2 = (con[:, 0] + con[:, 2]) * det2
    assert float((det2 / trace2 ** 2).min()) < 1e-3  # really near-singular
    # float32 stays finite and close to the float64 render
    p32 = {k: v.detach().float().requires_grad_() for k, v in p.items()}
    img32 = _render(rasterize, p32, cam)[0]
    assert torch.isfinite(img32).all()
    assert rel_err(img32.double(), fast[0].detach()) < 1e-3


def test_behind_and_crossing_near_plane():
    p = _scene(seed=2)
    cam = look_at_camera(eye=(0.0, 0.0, -4.0), near=0.2)
    # camera at z=-4 looking +z: world z = -4 + camera depth
    depth = np.r_[np.linspace(-3.0, -0.01, 10), [0.0, 0.1999, 0.2, 0.2001, 0.21, 0.25, 0.3]]
    rows = np.arange(len(depth))
    with torch.no_grad():
        p["means"][rows, 2] = torch.as_tensor(depth - 4.0)
        p["means"][rows, :2] *= 0.05  # on the optical axis
        p["log_scales"][rows] = -1.0  # big enough to cross the near plane
    fast, _, grads = compare(p, cam, 1e-4)
    radii = fast[3]["radii"].numpy()[rows]
    assert (radii[depth < 0.2] == 0).all()  # behind / in front of the near plane: culled
    assert (radii[depth > 0.2001] > 0).all()  # crossing it (centre beyond): rendered
    behind = torch.as_tensor(depth < 0.2)
    for k in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        assert float(grads[k][rows][behind].abs().max()) == 0.0, k


def test_huge_and_tiny_scales():
    p = _scene(seed=3)
    _set(p, "log_scales", slice(0, 3), 1.5)  # sigma 4.5: larger than the view
    _set(p, "opacity_logits", slice(0, 3), -3.0)
    _set(p, "log_scales", slice(3, 40), -18.0)  # far below a pixel
    fast, _, _ = compare(p, look_at_camera(), 1e-4)
    r = fast[3]["radii"]
    assert int(r[:3].max()) > 100
    assert ((r[3:40] > 0).sum() > 10) and int(r[3:40][r[3:40] > 0].max()) <= 3  # low-pass size
    # overflowing scales (exp(300)) are culled, never NaN
    _set(p, "log_scales", slice(0, 3), 300.0)
    fast, _, _ = compare(p, look_at_camera(), 1e-4)
    assert (fast[3]["radii"][:3] == 0).all()


def test_zero_opacity():
    p = _scene(seed=4)
    _set(p, "opacity_logits", slice(None), -60.0)  # sigmoid ~ 1e-26
    fast, _, grads = compare(p, look_at_camera(), 1e-4)
    img, alpha = fast[0].detach(), fast[1].detach()
    assert float(alpha.max()) == 0.0
    assert torch.equal(img, p["background"].detach().expand_as(img))
    for k in KEYS:
        assert float(grads[k].abs().max()) == 0.0


def test_extreme_aspect_ratios():
    p = _scene(seed=5)
    ls = np.full((120, 3), -9.0)
    ls[np.arange(120), np.arange(120) % 3] = -0.5  # needles 3500:1
    _set(p, "log_scales", slice(None), ls)
    fast, _, _ = compare(p, look_at_camera(), 1e-4)
    assert int((fast[3]["radii"] > 0).sum()) > 50


def test_camera_inside_a_gaussian():
    p = _scene(seed=6)
    cam = look_at_camera(eye=(0.0, 0.0, -4.0))
    # a big Gaussian whose centre is just in front of the camera: camera inside
    _set(p, "means", 0, [0.02, -0.01, -3.95])
    _set(p, "log_scales", 0, [0.0, 0.3, -0.2])
    _set(p, "opacity_logits", 0, 0.0)
    # one centred exactly on the camera: culled (z = 0 < near)
    _set(p, "means", 1, [0.0, 0.0, -4.0])
    _set(p, "log_scales", 1, [0.5, 0.5, 0.5])
    fast, _, grads = compare(p, cam, 1e-4)
    assert int(fast[3]["radii"][0]) > 100 and int(fast[3]["radii"][1]) == 0
    assert float(fast[1].detach().min()) > 0.3  # covers the whole view
    assert float(grads["means"][0].abs().max()) > 0


@pytest.mark.parametrize("key,bad", [("means", float("nan")), ("log_scales", float("inf")),
                                     ("quats", float("-inf")), ("opacity_logits", float("nan")),
                                     ("sh", float("nan")), ("background", float("nan"))])
def test_non_finite_parameters_raise(key, bad):
    p = _scene(seed=7)
    with torch.no_grad():
        p[key].view(-1)[2] = bad
    with pytest.raises(NonFiniteError, match=key):
        _render(rasterize, p, look_at_camera())


def test_zero_quaternion_and_bad_camera_raise():
    p = _scene(seed=8)
    _set(p, "quats", 3, 0.0)
    with pytest.raises(NonFiniteError, match="quats"):
        _render(rasterize, p, look_at_camera())
    p = _scene(seed=8)
    cam = look_at_camera()
    vm = cam.viewmat.copy()
    vm[0, 3] = np.nan
    bad = SplatCamera(vm, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height)
    with pytest.raises(NonFiniteError, match="camera"):
        _render(rasterize, p, bad)


def test_non_finite_upstream_gradient_raises():
    p = _scene(seed=9)
    img, alpha, depth, _ = _render(rasterize, p, look_at_camera())
    w = torch.ones_like(img)
    w[3, 4, 1] = float("nan")
    with pytest.raises(NonFiniteError, match="gradient of image"):
        (img * w).sum().backward()
    # expected depth divides by alpha; a NaN weight on depth is caught as well
    img, alpha, depth, _ = _render(rasterize, p, look_at_camera())
    with pytest.raises(NonFiniteError, match="gradient"):
        (depth * float("inf")).sum().backward()


def test_finite_check_survives_an_overflowing_sum():
    """The check sums first; a sum that overflows (all values finite) or
    cancels (inf and -inf) must fall back to the elementwise test."""
    from gs2e.splat.rasterize import NonFiniteError, _all_finite, check_finite

    big = torch.tensor([1e308, 1e308, -1.0], dtype=torch.float64)
    check_finite("big", big)  # sum is inf, values are not
    assert _all_finite(big.numpy()) and _all_finite(torch.zeros(0, 3))
    with pytest.raises(NonFiniteError, match=r"pm holds 2 non-finite value\(s\)"):
        check_finite("pm", torch.tensor([[np.inf, -np.inf], [0.0, 1.0]]))
    assert not _all_finite(np.array([1.0, np.nan], np.float32))
