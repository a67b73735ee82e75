"""Random test scenes for the splat tests (shared helpers, not a test module)."""

from __future__ import annotations

import numpy as np
import torch

from gs2e.splat.rasterize import SplatCamera


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
