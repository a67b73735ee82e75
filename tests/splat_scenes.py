"""Random test scenes for the splat tests (shared helpers, not a test module)."""

from __future__ import annotations

import numpy as np
import torch

from gs2e.splat.rasterize import SplatCamera, rasterize
from gs2e.splat.reference import render_reference


def look_at_camera(width=64, height=48, fx=None, eye=(0.0, 0.0, -4.0), near=0.01):
    """Camera at ``eye`` looking at the origin (world y down like OpenCV)."""
    eye = np.asarray(eye, dtype=np.float64)
    fwd = -eye / np.linalg.norm(eye)
    up = np.array([0.0, -1.0, 0.0])
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, down, fwd, eye
    fx = fx or 0.9 * width
    return SplatCamera.from_c2w(c2w, fx, fx * 1.05, width / 2 + 0.3, height / 2 - 0.7,
                                width, height, near=near)


def random_scene(n=300, seed=0, dtype=torch.float64, sh_degree=3, extent=1.5,
                 scale_range=(-3.5, -1.5)):
    """Random Gaussians around the origin; returns a dict of leaf tensors."""
    rng = np.random.default_rng(seed)
    K = (sh_degree + 1) ** 2
    sh = rng.normal(0, 0.3, (n, K, 3))
    sh[:, 0] = rng.normal(0, 1.0, (n, 3))
    p = dict(
        means=rng.uniform(-extent, extent, (n, 3)),
        quats=rng.normal(size=(n, 4)),
        log_scales=rng.uniform(*scale_range, (n, 3)),
        opacity_logits=rng.normal(0, 2.0, n),
        sh=sh,
        background=rng.uniform(0, 1, 3),
    )
    return {k: torch.tensor(v, dtype=dtype, requires_grad=True) for k, v in p.items()}


def rel_err(a: torch.Tensor, b: torch.Tensor) -> float:
    """max |a - b| / max |b| (max-norm relative error; 0 if both are 0)."""
    a, b = a.detach(), b.detach()
    den = float(b.abs().max()) if b.numel() else 0.0
    num = float((a - b).abs().max()) if a.numel() else 0.0
    if den == 0.0:
        return num
    return num / den


KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def _render(fn, p, cam, **kw):
    return fn(*(p[k] for k in KEYS), cam, p["background"], **kw)


def _loss(out, seed=0):
    """Random linear functional of image, alpha and depth (touches every output)."""
    img, alpha, depth, _ = out
    g = torch.Generator().manual_seed(seed)
    w = [torch.randn(x.shape, generator=g, dtype=x.dtype) for x in (img, alpha, depth)]
    return (img * w[0]).sum() + (alpha * w[1]).sum() + 0.1 * (depth * w[2]).sum()


def compare(p, cam, tol, **kw):
    """Assert outputs and every gradient match the reference within ``tol``
    (max-norm relative error); return (fast outputs, errors, fast gradients)."""
    fast = _render(rasterize, p, cam, **kw)
    grads = torch.autograd.grad(_loss(fast), [p[k] for k in (*KEYS, "background")])
    ref = _render(render_reference, p, cam, **kw)
    rgrads = torch.autograd.grad(_loss(ref), [p[k] for k in (*KEYS, "background")] + [ref[3]["means2d"]])
    errs = {n: rel_err(a.detach(), b.detach()) for n, a, b in zip(("image", "alpha", "depth"), fast, ref)}
    for k, a, b in zip((*KEYS, "background"), grads, rgrads):
        errs["d_" + k] = rel_err(a, b)
    vis = fast[3]["radii"] > 0
    errs["grad2d"] = rel_err(fast[3]["grad2d"][vis], rgrads[-1][vis].to(torch.float64))
    assert (fast[3]["radii"] == ref[3]["radii"]).all()
    bad = {k: v for k, v in errs.items() if not v <= tol}
    assert not bad, f"relative errors above {tol}: {bad}"
    for x in (*fast[:3], *grads):
        assert torch.isfinite(x).all()
    return fast, errs, dict(zip((*KEYS, "background"), grads))


