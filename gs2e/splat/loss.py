"""Image losses and quality metrics (torch): L1, SSIM (11x11 Gaussian window,
sigma 1.5, as 3DGS), PSNR. Images are (H, W, 3) or (B, H, W, 3) in [0, 1]."""

from __future__ import annotations

import functools
import math

import numpy as np
import torch
import torch.nn.functional as F
from numba import njit, prange

C1 = 0.01 ** 2
C2 = 0.03 ** 2


@functools.lru_cache(maxsize=8)
def _gauss_1d(size: int, sigma: float, dtype: torch.dtype) -> torch.Tensor:
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x ** 2) / (2 * sigma ** 2))
    return (g / g.sum()).to(dtype)


def _blur(x: torch.Tensor, size: int, sigma: float) -> torch.Tensor:
    """Separable Gaussian filter of (B, C, H, W), 'valid' borders like zero-padded
    3DGS SSIM would blur edges; we use zero padding of size//2 to match 3DGS."""
    c = x.shape[1]
    g = _gauss_1d(size, sigma, x.dtype)
    kx = g.view(1, 1, 1, size).expand(c, 1, 1, size)
    ky = g.view(1, 1, size, 1).expand(c, 1, size, 1)
    x = F.conv2d(x, kx, padding=(0, size // 2), groups=c)
    return F.conv2d(x, ky, padding=(size // 2, 0), groups=c)


def _bchw(img: torch.Tensor) -> torch.Tensor:
    if img.dim() == 3:
        img = img.unsqueeze(0)
    x = img.permute(0, 3, 1, 2)
    # Torch's CPU depthwise convolution is fast on channels-last float32 (the
    # permuted view: training) but has no such path for float64 (scores), which
    # runs 2-9x faster on contiguous NCHW (bench_isa.py's ssim_f64; docs/bench.md).
    return x.contiguous() if x.dtype == torch.float64 else x


def ssim_reference(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of two images (H, W, C) or (B, H, W, C), differentiable by
    torch's autograd through its depthwise convolutions: the definition
    :func:`ssim` is tested against, and what runs on a GPU."""
    x, y = _bchw(a), _bchw(b)
    mu_x, mu_y = _blur(x, window, sigma), _blur(y, window, sigma)
    sxx = _blur(x * x, window, sigma) - mu_x ** 2
    syy = _blur(y * y, window, sigma) - mu_y ** 2
    sxy = _blur(x * y, window, sigma) - mu_x * mu_y
    num = (2 * mu_x * mu_y + C1) * (2 * sxy + C2)
    den = (mu_x ** 2 + mu_y ** 2 + C1) * (sxx + syy + C2)
    return (num / den).mean()


def _blur_hwc(images: list[torch.Tensor], size: int, sigma: float) -> list[torch.Tensor]:
    """The same zero-padded separable Gaussian as :func:`_blur`, of CPU
    (B, H, W, C) float32/float64 tensors, channels last, by OpenCV's SIMD row
    and column filters: 7x less CPU than torch's depthwise convolution, equal
    to it within 3e-7 (float32) and 5e-16 (float64), and the same bits at any
    thread count (each output is one fixed sum). Each image stays a
    contiguous block: torch's elementwise ops on channel-interleaved views
    cost 6x those on contiguous ones."""
    import cv2

    g = _gauss_1d(size, sigma, images[0].dtype).numpy()
    out = []
    for img in images:
        src = img.detach().contiguous().numpy()
        blurred = torch.empty(img.shape, dtype=img.dtype)
        dst = blurred.numpy()
        for i in range(src.shape[0]):  # cv2 drops a channel axis of length 1: write through a reshape
            dst[i] = cv2.sepFilter2D(src[i], -1, g, g, borderType=cv2.BORDER_CONSTANT).reshape(dst[i].shape)
        out.append(blurred)
    return out


@njit(cache=True, parallel=True)
def _products(x, y, xx, yy, xy):
    """x², y², xy of flat arrays, in one pass."""
    for i in prange(x.shape[0]):
        xx[i] = x[i] * x[i]
        yy[i] = y[i] * y[i]
        xy[i] = x[i] * y[i]


@njit(inline="always", cache=True)
def _ssim_terms(mx, my, bxx, byy, bxy, c1, c2):
    """SSIM's numerator and denominator factors (a1, a2, b1, b2) of one pixel
    from its five blurs, in the order of operations of :func:`ssim_reference`
    (2 x computed exactly as x + x)."""
    d = bxy - mx * my
    return ((mx + mx) * my + c1, (d + d) + c2, (mx * mx + my * my) + c1,
            ((bxx - mx * mx) + (byy - my * my)) + c2)


@njit(cache=True, parallel=True)
def _ssim_map(mu_x, mu_y, bxx, byy, bxy, c1, c2, s_map):
    """The SSIM map from the five blurs (flat arrays; c1, c2 in their dtype),
    in the order of operations of :func:`ssim_reference`: the same bits as
    torch's elementwise ops, one pass instead of ~15 (each a memory sweep)."""
    for i in prange(mu_x.shape[0]):
        a1, a2, b1, b2 = _ssim_terms(mu_x[i], mu_y[i], bxx[i], byy[i], bxy[i], c1, c2)
        s_map[i] = (a1 * a2) / (b1 * b2)


@njit(cache=True, parallel=True)
def _ssim_back_maps(mu_x, mu_y, bxx, byy, bxy, c1, c2, g, s_map, own_x, own_y, d_x, d_y, d_bsq,
                    d_bxy):
    """Per pixel, the maps whose blurs make the gradient of mean SSIM (times
    ``g`` = upstream gradient / number of pixels): dL/d mu of each input wanted
    (``own_x``, ``own_y``) into d_x, d_y, dL/d blur(x²) = dL/d blur(y²) into
    d_bsq, dL/d blur(xy) into d_bxy."""
    for i in prange(mu_x.shape[0]):
        mx, my = mu_x[i], mu_y[i]
        a1, a2, b1, b2 = _ssim_terms(mx, my, bxx[i], byy[i], bxy[i], c1, c2)
        s = s_map[i]
        inv_b12 = g / (b1 * b2)
        dbxy = (a1 + a1) * inv_b12
        dbsq = (-g * s) / b2
        dcom = (a2 + a2) * inv_b12
        dmu = ((g + g) * s) / b1
        if own_x:
            d_x[i] = ((dcom * my - dmu * mx) - (mx + mx) * dbsq) - my * dbxy
        if own_y:
            d_y[i] = ((dcom * mx - dmu * my) - (my + my) * dbsq) - mx * dbxy
        d_bsq[i] = dbsq
        d_bxy[i] = dbxy


@njit(cache=True, parallel=True)
def _ssim_grad(b_mu, b_sq, b_xy, own, other, out):
    """d mean SSIM / d input = blur(dL/d mu) + 2 input blur(dL/d blur(sq))
    + other blur(dL/d blur(xy)), flat."""
    for i in prange(out.shape[0]):
        o = own[i]
        out[i] = (b_mu[i] + (o + o) * b_sq[i]) + other[i] * b_xy[i]


def _flat(t: torch.Tensor) -> np.ndarray:
    return t.detach().contiguous().numpy().reshape(-1)


class _SSIM(torch.autograd.Function):
    """Mean SSIM of (B, H, W, C) CPU images with its gradient in closed form:
    blurs of x, y, x², y² and xy forward, of three maps per input that needs a
    gradient backward (the zero-padded symmetric Gaussian is its own
    adjoint), each in OpenCV (:func:`_blur_hwc`); the per-pixel arithmetic
    around them in fused numba loops (a dozen torch elementwise ops each
    sweep the images: 0.1 of a DAVIS346 training step)."""

    @staticmethod
    def forward(ctx, x, y, window: int, sigma: float):
        xx, yy, xy = (torch.empty(x.shape, dtype=x.dtype) for _ in range(3))
        _products(_flat(x), _flat(y), _flat(xx), _flat(yy), _flat(xy))
        blurs = _blur_hwc([x, y, xx, yy, xy], window, sigma)
        c1, c2 = (_flat(x).dtype.type(c) for c in (C1, C2))
        s_map = torch.empty(x.shape, dtype=x.dtype)
        _ssim_map(*(_flat(b) for b in blurs), c1, c2, _flat(s_map))
        ctx.save_for_backward(x, y, *blurs, s_map)
        ctx.window, ctx.sigma, ctx.c = window, sigma, (c1, c2)
        return s_map.mean()

    @staticmethod
    def backward(ctx, grad):
        x, y, mu_x, mu_y, bxx, byy, bxy, s_map = ctx.saved_tensors
        need = ctx.needs_input_grad[:2]
        if not any(need):
            return None, None, None, None
        c1, c2 = ctx.c
        g = c1.dtype.type(float(grad)) / c1.dtype.type(s_map.numel())
        maps = [torch.empty(x.shape, dtype=x.dtype) for _ in range(4)]  # d_x, d_y, d_bsq, d_bxy
        flat = [_flat(m) for m in maps]
        _ssim_back_maps(*(_flat(b) for b in (mu_x, mu_y, bxx, byy, bxy)), c1, c2, g, _flat(s_map),
                        need[0], need[1], *flat)
        blurred = _blur_hwc([m for m, n in zip(maps, need + (True, True)) if n], ctx.window, ctx.sigma)
        b_sq, b_xy = blurred[-2], blurred[-1]
        grads, i = [None, None], 0
        for k, (own, other) in enumerate(((x, y), (y, x))):
            if need[k]:
                out = torch.empty(x.shape, dtype=x.dtype)
                _ssim_grad(_flat(blurred[i]), _flat(b_sq), _flat(b_xy), _flat(own), _flat(other),
                           _flat(out))
                grads[k] = out
                i += 1
        return grads[0], grads[1], None, None


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of two images (H, W, C) or (B, H, W, C), differentiable.

    On the CPU in float32/float64 the blurs run in OpenCV and the gradient in
    closed form (:class:`_SSIM`; a whole training step of temple_ring at
    349x260 spends 0.3 of its CPU in torch's version); elsewhere (a GPU, other
    dtypes) it is :func:`ssim_reference`. Both agree to rounding."""
    if (a.device.type != "cpu" or b.device.type != "cpu" or a.dtype != b.dtype
            or a.dtype not in (torch.float32, torch.float64)):
        return ssim_reference(a, b, window, sigma)
    x = a if a.dim() == 4 else a.unsqueeze(0)
    y = b if b.dim() == 4 else b.unsqueeze(0)
    return _SSIM.apply(x, y, window, float(sigma))


def l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a - b).abs().mean()


def photometric_loss(render: torch.Tensor, target: torch.Tensor, lambda_ssim: float = 0.2) -> torch.Tensor:
    """(1 - lambda) * L1 + lambda * (1 - SSIM), the 3DGS training loss."""
    return (1 - lambda_ssim) * l1(render, target) + lambda_ssim * (1 - ssim(render, target))


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB for images in [0, 1]; inf for identical images."""
    mse = float(((a.double() - b.double()) ** 2).mean())
    return math.inf if mse == 0 else -10.0 * math.log10(mse)
