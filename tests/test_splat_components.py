"""SH and projection kernels against torch autograd (float64)."""

import numpy as np
import pytest
import torch

from splat_scenes import look_at_camera, random_scene, rel_err
from gs2e.splat import project as P
from gs2e.splat import sh as S
from gs2e.splat.reference import project_reference, sh_basis


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_sh_forward_backward_match_autograd(degree):
    rng = np.random.default_rng(degree)
    n, K = 200, 16
    dirs = rng.normal(size=(n, 3)) * rng.uniform(0.1, 10, (n, 1))
    coeffs = rng.normal(0, 0.5, (n, K, 3))
    coeffs[:, 0] = rng.normal(0, 2.0, (n, 3))
    col, ok = S.sh_to_color(dirs, coeffs, degree)
    d_t = torch.tensor(dirs, requires_grad=True)
    c_t = torch.tensor(coeffs, requires_grad=True)
    nb = (degree + 1) ** 2
    ref = torch.relu(torch.einsum("nk,nkc->nc", sh_basis(d_t / d_t.norm(dim=1, keepdim=True), degree),
                                  c_t[:, :nb]) + 0.5)
    assert rel_err(torch.from_numpy(col), ref.detach()) < 1e-13
    assert (~ok).any() and ok.any()  # the clamp at 0 is exercised
    g = rng.normal(size=(n, 3))
    gc_ref, gd_ref = torch.autograd.grad((ref * torch.tensor(g)).sum(), [c_t, d_t], allow_unused=True)
    gc, gd = S.sh_to_color_backward(dirs, coeffs, degree, ok, g)
    assert rel_err(torch.from_numpy(gc), gc_ref) < 1e-12
    assert np.all(gc[:, nb:] == 0)
    if degree == 0:
        assert np.all(gd == 0)
    else:
        assert rel_err(torch.from_numpy(gd), gd_ref) < 1e-12


def test_sh_rejects_bad_degree():
    with pytest.raises(ValueError):
        S.sh_to_color(np.ones((2, 3)), np.ones((2, 4, 3)), 2)  # needs 9 coefficients
    with pytest.raises(ValueError):
        S.num_sh_bases(4)


def test_projection_matches_reference_and_autograd():
    p = random_scene(400, seed=3, extent=3.0)  # some behind / off-screen
    cam = look_at_camera(eye=(0.3, -0.2, -3.0))
    m, q, ls = (p[k] for k in ("means", "quats", "log_scales"))
    means2d, conics, depths, radii = P.project(m.detach().numpy(), q.detach().numpy(),
                                               ls.detach().numpy(), cam.viewmat, cam.fx, cam.fy,
                                               cam.cx, cam.cy, cam.width, cam.height, cam.near)
    r2d, rcon, rz, rrad = project_reference(m, q, ls, cam)
    vis = radii > 0
    assert (rrad.numpy() == radii).all()
    assert 0 < vis.sum() < len(vis)  # some culled, some visible
    assert rel_err(torch.from_numpy(means2d[vis]), r2d.detach()[vis]) < 1e-13
    assert rel_err(torch.from_numpy(conics[vis]), rcon.detach()[vis]) < 1e-12
    assert rel_err(torch.from_numpy(depths), rz.detach()) < 1e-14
    rng = np.random.default_rng(0)
    g2, gc, gz = rng.normal(size=(400, 2)), rng.normal(size=(400, 3)) * 10, rng.normal(size=400)
    vis_t = torch.from_numpy(vis)
    loss = ((r2d * torch.tensor(g2)).sum(1) + (rcon * torch.tensor(gc)).sum(1) + rz * torch.tensor(gz))
    ref = torch.autograd.grad(loss[vis_t].sum(), [m, q, ls])
    got = P.project_backward(m.detach().numpy(), q.detach().numpy(), ls.detach().numpy(),
                             cam.viewmat, cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                             radii, g2, gc, gz)
    for name, a, b in zip(("means", "quats", "log_scales"), got, ref):
        assert rel_err(torch.from_numpy(a), b) < 1e-11, name
        assert np.all(a[~vis] == 0), name


def test_projection_of_a_subset_writes_only_its_rows():
    """project_cov with idx projects those rows exactly as the whole projection
    does and leaves every other row (all of them for an empty idx) as it was."""
    p = random_scene(300, seed=5, extent=3.0)
    cam = look_at_camera(eye=(0.2, 0.1, -3.0))
    m = p["means"].detach().numpy()
    cov6 = np.empty((len(m), 6))
    P.cov3d_kernel(p["quats"].detach().numpy(), p["log_scales"].detach().numpy(), cov6)

    def proj(idx, out=None):
        return P.project_cov(m, cov6, cam.viewmat, cam.fx, cam.fy, cam.cx, cam.cy, cam.width,
                             cam.height, cam.near, idx=idx, out=out)

    whole = proj(None)
    assert (whole[3] > 0).any()
    stale = tuple(np.full_like(a, 7) for a in whole)
    idx = np.arange(1, len(m), 3)
    got = proj(idx, tuple(a.copy() for a in stale))
    rest = np.setdiff1d(np.arange(len(m)), idx)
    for a, s, w in zip(got, stale, whole):
        assert np.array_equal(a[idx], w[idx]) and np.array_equal(a[rest], s[rest])
    got = proj(np.empty(0, np.int64), tuple(a.copy() for a in stale))
    assert all(np.array_equal(a, s) for a, s in zip(got, stale))


def test_jacobian_clamp_far_off_screen():
    """A Gaussian far off to the side but with a huge footprint: the 1.3x FOV
    clamp of the Jacobian must act, and its gradient must match autograd."""
    cam = look_at_camera()
    m = torch.tensor([[3.5, 0.2, -2.0]], dtype=torch.float64, requires_grad=True)  # x/z >> fov
    q = torch.tensor([[1.0, 0.2, 0.1, 0.0]], dtype=torch.float64, requires_grad=True)
    ls = torch.tensor([[0.8, 0.5, 0.3]], dtype=torch.float64, requires_grad=True)
    r2d, rcon, rz, rrad = project_reference(m, q, ls, cam)
    assert rrad[0] > 0
    mm = m.detach().numpy()
    vm = cam.viewmat
    pc = vm[:3, :3] @ mm[0] + vm[:3, 3]
    assert pc[0] / pc[2] > (cam.width - cam.cx) / cam.fx * 1.3  # clamped branch
    loss = (r2d.sum() + rcon.sum() * 100 + rz.sum())
    ref = torch.autograd.grad(loss, [m, q, ls])
    _, _, _, radii = P.project(mm, q.detach().numpy(), ls.detach().numpy(), vm, cam.fx, cam.fy,
                               cam.cx, cam.cy, cam.width, cam.height)
    got = P.project_backward(mm, q.detach().numpy(), ls.detach().numpy(), vm, cam.fx, cam.fy,
                             cam.cx, cam.cy, cam.width, cam.height, radii,
                             np.ones((1, 2)), np.full((1, 3), 100.0), np.ones(1))
    for a, b in zip(got, ref):
        assert rel_err(torch.from_numpy(a), b) < 1e-11
