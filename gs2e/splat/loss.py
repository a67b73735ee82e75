"""Image losses and quality metrics (torch): L1, SSIM (11x11 Gaussian window,
sigma 1.5, as 3DGS), PSNR. Images are (H, W, 3) or (B, H, W, 3) in [0, 1]."""

from __future__ import annotations

import functools
import math

import torch
import torch.nn.functional as F

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


def ssim(a: torch.Tensor, b: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of two images (H, W, C) or (B, H, W, C), differentiable."""
    x, y = _bchw(a), _bchw(b)
    mu_x, mu_y = _blur(x, window, sigma), _blur(y, window, sigma)
    sxx = _blur(x * x, window, sigma) - mu_x ** 2
    syy = _blur(y * y, window, sigma) - mu_y ** 2
    sxy = _blur(x * y, window, sigma) - mu_x * mu_y
    num = (2 * mu_x * mu_y + C1) * (2 * sxy + C2)
    den = (mu_x ** 2 + mu_y ** 2 + C1) * (sxx + syy + C2)
    return (num / den).mean()


def l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return (a - b).abs().mean()


def photometric_loss(render: torch.Tensor, target: torch.Tensor, lambda_ssim: float = 0.2) -> torch.Tensor:
    """(1 - lambda) * L1 + lambda * (1 - SSIM), the 3DGS training loss."""
    return (1 - lambda_ssim) * l1(render, target) + lambda_ssim * (1 - ssim(render, target))


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB for images in [0, 1]; inf for identical images."""
    mse = float(((a.double() - b.double()) ** 2).mean())
    return math.inf if mse == 0 else -10.0 * math.log10(mse)
