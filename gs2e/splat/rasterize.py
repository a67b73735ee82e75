"""Differentiable Gaussian-splatting render on the CPU (torch autograd wrapper).

``rasterize(params..., cam)`` projects, evaluates SH colour, bins to tiles,
composites front to back and returns image, alpha and expected depth. The
backward pass is hand written (numba kernels in :mod:`gs2e.splat.raster`,
:mod:`gs2e.splat.project`, :mod:`gs2e.splat.sh`), never autograd through
per-pixel x per-Gaussian tensors.

Precision: outputs take the inputs' dtype (float32 or float64); projection and
SH always run in float64 (O(N), cheap, robust for near-singular covariances).
Compositing computes in float32 where no gradient can follow, and in
``grad_dtype`` (float64 by default, or float32) where one may: the backward
recomputes the forward's power, exp and alpha in that type, so both must agree.
Results are bit-identical between runs and thread counts.

Choice of numba over a C++ extension (measured by
benchmarks/bench_rasterizer.py): the pixel-major compositing loop compiled with
gcc -O3 -march=native -fopenmp ran at 0.9-1.1x the numba kernel of the same
loop; the SIMD kernels of :mod:`gs2e.splat.raster` now run 2.6x faster than
that C build, so an extra build step buys nothing; numba installs with pip
alone.

Non-finite values in parameters, camera or upstream gradients raise
:class:`NonFiniteError` naming the tensor; they are never propagated.
"""

from __future__ import annotations


from dataclasses import dataclass

import numpy as np
import torch
from scipy.special import expit

from gs2e.common.errors import InputError
from gs2e.splat.finite import NonFiniteError, all_finite as _all_finite, check_finite
from gs2e.splat import project as _proj
from gs2e.splat import raster as _raster
from gs2e.splat import sh as _sh

TILE = 16


@dataclass(frozen=True)
class SplatCamera:
    """Pinhole camera for rendering.

    viewmat : (4,4) world-to-camera, OpenCV axes (x right, y down, z forward).
    fx, fy, cx, cy : intrinsics in px (pixel centres at integer + 0.5).
    width, height : image size in px.
    near, far : depth range in scene units (camera z); Gaussians whose centre
        lies outside are culled.
    """

    viewmat: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near: float = 0.01
    far: float = 1.0e10

    @staticmethod
    def from_c2w(c2w, fx, fy, cx, cy, width, height, near=0.01, far=1.0e10):
        """Build from a camera-to-world 4x4 (as in gs2e.io.scene)."""
        c2w = np.asarray(c2w, dtype=np.float64)
        w2c = np.eye(4)
        w2c[:3, :3] = c2w[:3, :3].T
        w2c[:3, 3] = -c2w[:3, :3].T @ c2w[:3, 3]
        return SplatCamera(w2c, float(fx), float(fy), float(cx), float(cy),
                           int(width), int(height), float(near), float(far))

    def validate(self) -> np.ndarray:
        vm = np.asarray(self.viewmat.detach().cpu().numpy() if torch.is_tensor(self.viewmat)
                        else self.viewmat, dtype=np.float64)
        if vm.shape != (4, 4):
            raise InputError(f"camera viewmat must be 4x4, got shape {vm.shape}")
        vals = np.array([self.fx, self.fy, self.cx, self.cy, self.near], dtype=np.float64)
        if not (np.isfinite(vm).all() and np.isfinite(vals).all()):
            raise NonFiniteError("camera viewmat/intrinsics contain NaN or inf")
        if self.fx <= 0 or self.fy <= 0 or self.width <= 0 or self.height <= 0:
            raise InputError(f"camera needs fx, fy, width, height > 0, got "
                             f"fx={self.fx} fy={self.fy} width={self.width} height={self.height}")
        if not 0 < self.near < self.far:
            raise InputError(f"camera needs 0 < near < far, got near={self.near} far={self.far}")
        return vm

    def campos(self) -> np.ndarray:
        """Camera centre in world coordinates (3,)."""
        vm = self.validate()
        return -vm[:3, :3].T @ vm[:3, 3]


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().cpu().contiguous().numpy()


class _Rasterize(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, logscales, opacity_logits, sh, background,
                cam, sh_degree, meta, forward_only, grad_dtype, window):
        dt = means.dtype
        ndt = np.float64 if dt == torch.float64 else np.float32
        vm = cam.validate()
        m = _np(means)
        q = _np(quats)
        ls = _np(logscales)
        shc = _np(sh)
        W, H = int(cam.width), int(cam.height)
        means2d, conics, depths, radii = _proj.project(
            m, q, ls, vm, cam.fx, cam.fy, cam.cx, cam.cy, W, H, cam.near, cam.far)
        campos = -vm[:3, :3].T @ vm[:3, 3]
        dirs = m.astype(np.float64) - campos[None, :]
        colors, ok = _sh.sh_to_color(dirs, shc, sh_degree)
        opac = expit(_np(opacity_logits).astype(np.float64))
        feats = np.ascontiguousarray(np.concatenate([colors, depths[:, None]], axis=1), dtype=ndt)
        bg4 = np.zeros(4, dtype=ndt)
        bg4[:3] = _np(background)
        offsets, gids = _raster.bin_gaussians(means2d, depths, radii, W, H, TILE, opac)
        m2 = means2d.astype(ndt)
        cn = conics.astype(ndt)
        op = opac.astype(ndt)
        # a forward that a backward may follow computes in the backward's dtype
        compute = ndt if forward_only else grad_dtype
        out, out_T, n_contrib = _raster.rasterize_forward(
            m2, cn, op, feats, bg4, W, H, offsets, gids, TILE, compute_dtype=compute, window=window)
        ctx.compute = compute
        ctx.window = window
        ctx.cam = cam
        ctx.sh_degree = sh_degree
        ctx.meta = meta
        ctx.np_saved = (m, q, ls, shc, vm, means2d, radii, dirs, ok, opac,
                        m2, cn, op, feats, bg4, offsets, gids, out_T, n_contrib)
        meta["radii"] = torch.from_numpy(radii)
        meta["means2d"] = torch.from_numpy(means2d)
        meta["depths"] = torch.from_numpy(depths)
        meta["conics"] = torch.from_numpy(conics)
        meta["n_pairs"] = int(gids.shape[0])
        meta["grad2d"] = torch.zeros((m.shape[0], 2), dtype=torch.float64)
        image = torch.from_numpy(np.ascontiguousarray(out[..., :3]))
        alpha = torch.from_numpy(1.0 - out_T)
        depth_acc = torch.from_numpy(np.ascontiguousarray(out[..., 3]))
        return image, alpha, depth_acc

    @staticmethod
    def backward(ctx, g_img, g_alpha, g_dacc):
        (m, q, ls, shc, vm, means2d, radii, dirs, ok, opac,
         m2, cn, op, feats, bg4, offsets, gids, out_T, n_contrib) = ctx.np_saved
        cam = ctx.cam
        W, H = int(cam.width), int(cam.height)
        n = m.shape[0]
        zeros = np.zeros((H, W))
        gi = _np(g_img).astype(np.float64) if g_img is not None else np.zeros((H, W, 3))
        ga = _np(g_alpha).astype(np.float64) if g_alpha is not None else zeros
        gd = _np(g_dacc).astype(np.float64) if g_dacc is not None else zeros
        for name, arr in (("gradient of image", gi), ("gradient of alpha", ga),
                          ("gradient of depth", gd)):
            if not _all_finite(arr):
                raise NonFiniteError(f"upstream {name} holds {int((~np.isfinite(arr)).sum())} "
                                     "non-finite value(s)")
        g_out = np.ascontiguousarray(np.concatenate([gi, gd[..., None]], axis=2))
        # image = C + T*bg and alpha = 1 - T
        g_T = np.ascontiguousarray(gi @ bg4[:3].astype(np.float64) - ga)
        grads = _raster.rasterize_backward(m2, cn, op, feats, W, H, offsets, gids,
                                           out_T, n_contrib, g_out, g_T, TILE, ctx.compute,
                                           ctx.window)
        g_means2d = np.ascontiguousarray(grads[:, 0:2])
        g_conics = np.ascontiguousarray(grads[:, 2:5])
        g_logit = grads[:, 5] * opac * (1.0 - opac)
        g_colors = np.ascontiguousarray(grads[:, 6:9])
        g_depths = np.ascontiguousarray(grads[:, 9])
        g_sh, g_dirs = _sh.sh_to_color_backward(dirs, shc, ctx.sh_degree, ok, g_colors)
        g_means, g_quats, g_ls = _proj.project_backward(
            m, q, ls, vm, cam.fx, cam.fy, cam.cx, cam.cy, W, H, radii,
            g_means2d, g_conics, g_depths)
        g_means += g_dirs
        # only when asked for: a fixed background (training) would pay ~4 ms a
        # step at 640 px for this strided sum
        g_bg = ((gi * out_T[..., None].astype(np.float64)).reshape(-1, 3).sum(axis=0)
                if ctx.needs_input_grad[5] else None)
        ctx.meta["grad2d"].copy_(torch.from_numpy(g_means2d))
        dt = torch.float64 if feats.dtype == np.float64 else torch.float32
        out = []
        for name, arr in (("means", g_means), ("quats", g_quats), ("log_scales", g_ls),
                          ("opacity_logits", g_logit), ("sh", g_sh), ("background", g_bg)):
            if arr is None:
                out.append(None)
                continue
            if not _all_finite(arr):
                raise NonFiniteError(f"gradient of {name} holds "
                                     f"{int((~np.isfinite(arr)).sum())} non-finite value(s)")
            out.append(torch.from_numpy(np.ascontiguousarray(arr)).to(dt))
        return (*out, None, None, None, None, None, None)


def rasterize(means: torch.Tensor, quats: torch.Tensor, log_scales: torch.Tensor,
              opacity_logits: torch.Tensor, sh: torch.Tensor, cam: SplatCamera,
              background: torch.Tensor | None = None, sh_degree: int | None = None,
              check: bool = True, backend: str = "cpu", grad_dtype: str = "float64",
              window: str = "cut"):
    """Render Gaussians with a differentiable CPU rasterizer.

    Parameters
    ----------
    means : (N,3) world positions.
    quats : (N,4) rotations (w,x,y,z), any non-zero norm.
    log_scales : (N,3) natural-log standard deviations (scene units).
    opacity_logits : (N,) opacity before the sigmoid.
    sh : (N,K,3) SH coefficients, K in {1,4,9,16}; colour = SH + 0.5, >= 0.
    cam : SplatCamera.
    background : (3,) colour behind the Gaussians (default black).
    sh_degree : active degree (default: the largest K allows).
    check : raise NonFiniteError on NaN/inf parameters (cheap; keep on).
    backend : 'cpu' (this module's rasterizer) or 'gsplat' (CUDA, optional;
        see :mod:`gs2e.splat.backend`; resolve 'auto' with ``resolve_backend``).
    grad_dtype : what the CPU compositing computes in when a gradient may be
        asked for: 'float64' (8 lanes, products and sums rounded one by one)
        or 'float32' (16 lanes, fused multiply-adds; about 1.5x faster); its
        backward recomputes in the same type.
    window : the compositing window, 'cut' (3DGS's: each Gaussian cut at 3
        sigma and alpha 1/255, compositing stopped at transmittance 1e-4) or
        'smooth' (the same footprint tapered to zero with its slope, weights
        faded before the stop: images continuous in the camera pose; issue
        67, :mod:`gs2e.splat.raster`). The CUDA backend has 'cut' only.

    All tensors share one dtype, float32 or float64 (outputs take it). Where
    no gradient can be asked for (grad mode off or no input requiring one) the
    compositing computes in that dtype, else in ``grad_dtype``.

    Returns
    -------
    image (H,W,3), alpha (H,W) = 1 - final transmittance, depth (H,W) expected
    camera z (accumulated depth / alpha, 0 where alpha = 0), and a meta dict:
    radii (N,) int px (0 = culled), means2d (N,2) px, depths (N,), conics (N,3),
    n_pairs (Gaussian-tile pairs) and grad2d (N,2), the gradient of the loss
    w.r.t. the 2D means in px, filled in by the backward pass (densification).
    """
    N = means.shape[0]
    dt = means.dtype
    if dt not in (torch.float32, torch.float64):
        raise InputError(f"means must be float32 or float64, got {dt}")
    if background is None:
        background = torch.zeros(3, dtype=dt)
    shapes = {"means": (means, (N, 3)), "quats": (quats, (N, 4)),
              "log_scales": (log_scales, (N, 3)), "opacity_logits": (opacity_logits, (N,)),
              "background": (background, (3,))}
    for name, (x, shp) in shapes.items():
        if tuple(x.shape) != shp:
            raise InputError(f"{name} must have shape {shp}, got {tuple(x.shape)}")
        if x.dtype != dt:
            raise InputError(f"{name} has dtype {x.dtype}, expected {dt} like means")
    if sh.dim() != 3 or sh.shape[0] != N or sh.shape[2] != 3 or sh.shape[1] not in (1, 4, 9, 16):
        raise InputError(f"sh must have shape (N,K,3) with K in 1,4,9,16, got {tuple(sh.shape)}")
    if sh.dtype != dt:
        raise InputError(f"sh has dtype {sh.dtype}, expected {dt} like means")
    max_deg = int(round(sh.shape[1] ** 0.5)) - 1
    if sh_degree is None:
        sh_degree = max_deg
    if not 0 <= sh_degree <= max_deg:
        raise InputError(f"sh_degree {sh_degree} needs K >= {(sh_degree + 1) ** 2}, got {sh.shape[1]}")
    if check:
        for name, (x, _) in shapes.items():
            check_finite(name, x)
        check_finite("sh", sh)
        qn = quats.detach().norm(dim=1)
        if bool((qn == 0).any()):
            raise NonFiniteError(f"quats has zero-norm rows {torch.nonzero(qn == 0)[:5].flatten().tolist()}")
    if window not in _raster.WINDOWS:
        raise InputError(f"rasterize: window must be one of {', '.join(_raster.WINDOWS)}, got {window!r}")
    if backend == "gsplat":
        if window != "cut":
            raise InputError("rasterize: the gsplat backend composites with the 'cut' window only; "
                             "use backend 'cpu' for window 'smooth'")
        from gs2e.splat.backend import rasterize_gsplat

        return rasterize_gsplat(means, quats, log_scales, opacity_logits, sh, cam, background,
                                int(sh_degree))
    if backend != "cpu":
        raise InputError(f"rasterize: backend must be 'cpu' or 'gsplat', got {backend!r}")
    if grad_dtype not in ("float32", "float64"):
        raise InputError(f"rasterize: grad_dtype must be 'float32' or 'float64', got {grad_dtype!r}")
    meta: dict = {}
    forward_only = not (torch.is_grad_enabled() and any(
        x.requires_grad for x in (means, quats, log_scales, opacity_logits, sh, background)))
    image, alpha, depth_acc = _Rasterize.apply(means, quats, log_scales, opacity_logits, sh,
                                               background, cam, int(sh_degree), meta, forward_only,
                                               np.dtype(grad_dtype).type, window)
    depth = depth_acc / alpha.clamp_min(1e-10)
    return image, alpha, depth, meta

