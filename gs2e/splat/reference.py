"""Dense pure-torch Gaussian-splatting renderer with autograd, for tests only.

Same math as :func:`gs2e.splat.rasterize.rasterize` (projection, low-pass,
Jacobian clamp, culling, SH, 3-sigma cut, alpha clamps, early stop) but
evaluated on a dense (pixels x Gaussians) grid and differentiated by autograd.
Memory is O(H*W*N): only for small scenes.
"""

from __future__ import annotations

import math

import torch

from gs2e.splat import raster as _r
from gs2e.splat.project import LOWPASS_PX2, MAX_RADIUS_PX
from gs2e.splat.sh import C0, C1, C2, C3


def quat_to_rot(q: torch.Tensor) -> torch.Tensor:
    """(N,4) (w,x,y,z), any norm -> (N,3,3) rotation matrices."""
    q = q / q.norm(dim=1, keepdim=True)
    w, x, y, z = q.unbind(1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=1).reshape(-1, 3, 3)


def sh_basis(d: torch.Tensor, degree: int) -> torch.Tensor:
    """(N,3) unit directions -> (N,(degree+1)^2) real SH basis values."""
    x, y, z = d.unbind(1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        out += [C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy),
                C2[3] * x * z, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
                C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
                C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)]
    return torch.stack(out, dim=1)


def project_reference(means, quats, log_scales, cam):
    """Differentiable projection. Returns means2d (N,2), conics (N,3), z (N,),
    radii (N,) (no grad) with the culling rules of the fast path."""
    dt = means.dtype
    vm = torch.as_tensor(cam.validate(), dtype=dt)
    R, t = vm[:3, :3], vm[:3, 3]
    p = means @ R.T + t
    x, y, z = p.unbind(1)
    # culled rows get harmless stand-in values so no NaN enters autograd
    front = ((z >= cam.near) & (z <= cam.far)).detach()
    z = torch.where(front, z, torch.ones_like(z))
    W, H = float(cam.width), float(cam.height)
    lim_xp = (W - cam.cx) / cam.fx + 0.3 * W / cam.fx
    lim_xn = cam.cx / cam.fx + 0.3 * W / cam.fx
    lim_yp = (H - cam.cy) / cam.fy + 0.3 * H / cam.fy
    lim_yn = cam.cy / cam.fy + 0.3 * H / cam.fy
    tx = z * torch.clamp(x / z, -lim_xn, lim_xp)
    ty = z * torch.clamp(y / z, -lim_yn, lim_yp)
    zero = torch.zeros_like(z)
    J = torch.stack([cam.fx / z, zero, -cam.fx * tx / z ** 2,
                     zero, cam.fy / z, -cam.fy * ty / z ** 2], dim=1).reshape(-1, 2, 3)
    Rq = quat_to_rot(quats)
    M = Rq * torch.exp(log_scales)[:, None, :]
    S3 = M @ M.transpose(1, 2)
    Sc = R @ S3 @ R.T
    S2 = J @ Sc @ J.transpose(1, 2)
    a = S2[:, 0, 0] + LOWPASS_PX2
    b = S2[:, 0, 1]
    c = S2[:, 1, 1] + LOWPASS_PX2
    det = a * c - b * b
    ok = front & (det > 0).detach()
    det = torch.where(ok, det, torch.ones_like(det))
    conics = torch.stack([c / det, -b / det, a / det], dim=1)
    u = cam.fx * x / z + cam.cx
    v = cam.fy * y / z + cam.cy
    with torch.no_grad():
        mid = 0.5 * (a + c)
        lam = mid + torch.sqrt(torch.clamp(mid * mid - det, min=0.1))
        r = torch.ceil(torch.clamp(3 * torch.sqrt(lam), max=MAX_RADIUS_PX))
        inside = (u + r >= 0.5) & (u - r <= W - 0.5) & (v + r >= 0.5) & (v - r <= H - 0.5)
        radii = torch.where(ok & inside, r, torch.zeros_like(r)).to(torch.int64)
    return torch.stack([u, v], dim=1), conics, p[:, 2], radii


def reference_colors(means, sh, campos, sh_degree: int) -> torch.Tensor:
    """(N, 3) view-dependent colours of Gaussians at ``means`` (N, 3) seen
    from ``campos`` (3,): SH of degree ``sh_degree`` (``sh`` (N, K, 3)) + 0.5,
    clamped at 0, as the rasteriser evaluates them."""
    dirs = means - campos
    nrm = dirs.norm(dim=1, keepdim=True)
    dirs = dirs / torch.where(nrm > 0, nrm, torch.ones_like(nrm))
    nb = (sh_degree + 1) ** 2
    return torch.relu(torch.einsum("nk,nkc->nc", sh_basis(dirs, sh_degree), sh[:, :nb]) + 0.5)


def reference_alpha(power: torch.Tensor, opac: torch.Tensor) -> torch.Tensor:
    """(P, M) alpha of M depth-ordered Gaussians at P pixels from their
    Gaussian exponent ``power`` (P, M) and opacities ``opac`` (M,), with the
    rasteriser's window: cut beyond 3 sigma (POWER_MIN) and below ALPHA_MIN,
    clamped at ALPHA_MAX, and zero once a pixel's transmittance falls below
    T_MIN (the early stop). The cuts are not differentiated."""
    inside = ((power <= 0) & (power >= _r.POWER_MIN)).detach()
    power = torch.where(inside, power, torch.full_like(power, -100.0))
    alpha = torch.clamp(opac[None, :] * torch.exp(power), max=_r.ALPHA_MAX)
    keep = inside & (alpha >= _r.ALPHA_MIN).detach()
    alpha = torch.where(keep, alpha, torch.zeros_like(alpha))
    with torch.no_grad():
        stop = torch.cumprod(1 - alpha, dim=1) < _r.T_MIN
    return torch.where(stop, torch.zeros_like(alpha), alpha)


def reference_weights(power: torch.Tensor, opac: torch.Tensor, window: str = "cut"):
    """Compositing weights (P, M) of M depth-ordered Gaussians at P pixels and
    the final transmittance (P,), with the rasteriser's ``window``
    (:data:`gs2e.splat.raster.WINDOWS`): ``cut`` (:func:`reference_alpha`,
    w = alpha T) or ``smooth`` (alpha = o phi(p) / phi(0), phi = e^p less its
    tangent at the Gaussian's cut p_c; w = alpha T r(T), the Gaussian that
    takes T below T_MIN applied: :mod:`gs2e.splat.raster`). Which pixels a Gaussian reaches
    and where a pixel stops are not differentiated."""
    _r.check_window(window)
    one = torch.ones_like(power[:, :1])
    if window == "cut":
        alpha = reference_alpha(power, opac)
        T = torch.cumprod(torch.cat([one, 1 - alpha[:, :-1]], dim=1), dim=1)
        T_final = torch.prod(1 - alpha, dim=1) if alpha.shape[1] else one[:, 0]
        return alpha * T, T_final
    o = opac[None, :]
    e0 = math.exp(_r.POWER_MIN)
    big = (o * e0 >= _r.ALPHA_MIN).detach()
    pc = torch.where(big, torch.full_like(o, _r.POWER_MIN), torch.log(_r.ALPHA_MIN / o))
    ec = torch.exp(pc)
    phi0 = 1 - ec * (1 - pc)
    drawn = (o >= _r.ALPHA_MIN) & (phi0 >= _r.SMOOTH_PHI0_MIN).detach()
    inside = ((power <= 0) & (power >= pc) & drawn).detach()
    p = torch.where(inside, power, torch.zeros_like(power))
    raw = o * (torch.exp(p) - ec * (1 + p - pc)) / torch.where(drawn, phi0, torch.ones_like(phi0))
    alpha = torch.where(inside, torch.clamp(raw, min=0.0, max=_r.ALPHA_MAX), torch.zeros_like(raw))
    T = torch.cumprod(torch.cat([one, 1 - alpha[:, :-1]], dim=1), dim=1)
    with torch.no_grad():  # pixels stop after the Gaussian that takes T below T_MIN
        after = torch.cat([torch.zeros_like(one, dtype=torch.bool), (T * (1 - alpha) < _r.T_MIN)[:, :-1]],
                          dim=1)
        after = torch.cumsum(after.to(torch.int64), dim=1) > 0
    alpha = torch.where(after, torch.zeros_like(alpha), alpha)
    T = torch.cumprod(torch.cat([one, 1 - alpha[:, :-1]], dim=1), dim=1)
    x = torch.clamp((T - _r.T_MIN) / _r.T_MIN, 0.0, 1.0)
    T_final = torch.prod(1 - alpha, dim=1) if alpha.shape[1] else one[:, 0]
    return alpha * T * x * x * (3 - 2 * x), T_final


def render_reference(means, quats, log_scales, opacity_logits, sh, cam,
                     background=None, sh_degree=None, window="cut"):
    """Dense render; same signature and outputs (image, alpha, depth, meta) as
    :func:`gs2e.splat.rasterize.rasterize` (``window``: the rasteriser's,
    :func:`reference_weights`); meta holds means2d (with grad, retain_grad()
    called) and radii."""
    dt = means.dtype
    if background is None:
        background = torch.zeros(3, dtype=dt)
    if sh_degree is None:
        sh_degree = int(round(sh.shape[1] ** 0.5)) - 1
    means2d, conics, z, radii = project_reference(means, quats, log_scales, cam)
    means2d.retain_grad()
    vis = radii > 0
    col = reference_colors(means, sh, torch.as_tensor(cam.campos(), dtype=dt), sh_degree)
    opac = torch.sigmoid(opacity_logits)
    W, H = int(cam.width), int(cam.height)
    # depth order (stable, ties by index), visible only
    idx = torch.nonzero(vis).flatten()
    idx = idx[torch.sort(z.detach()[idx], stable=True).indices]
    u, v = means2d[idx, 0], means2d[idx, 1]
    A, B, Cc = conics[idx].unbind(1)
    jj, ii = torch.meshgrid(torch.arange(W, dtype=dt) + 0.5, torch.arange(H, dtype=dt) + 0.5,
                            indexing="xy")
    px = jj.reshape(-1, 1)
    py = ii.reshape(-1, 1)
    dx = u[None, :] - px
    dy = v[None, :] - py
    power = -0.5 * (A * dx * dx + Cc * dy * dy) - B * dx * dy
    w, T_final = reference_weights(power, opac[idx], window)
    rgb = w @ col[idx] + T_final[:, None] * background[None, :]
    dacc = w @ z[idx]
    image = rgb.reshape(H, W, 3)
    a_img = (1 - T_final).reshape(H, W)
    depth = dacc.reshape(H, W) / a_img.clamp_min(1e-10)
    return image, a_img, depth, {"means2d": means2d, "radii": radii}
