"""SSIM/PSNR losses and SfM-point initialisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gs2e.common.errors import InputError
from gs2e.splat.init import SH_C0, init_from_points, knn_log_scales
from gs2e.splat.loss import photometric_loss, psnr, ssim


def test_ssim_identity_and_range():
    g = torch.Generator().manual_seed(0)
    a = torch.rand(32, 40, 3, generator=g, dtype=torch.float64)
    assert float(ssim(a, a)) == pytest.approx(1.0, abs=1e-12)
    b = torch.rand(32, 40, 3, generator=g, dtype=torch.float64)
    assert -1 < float(ssim(a, b)) < 0.2
    assert psnr(a, a) == math.inf


def test_ssim_matches_skimage_on_interior():
    from skimage.metrics import structural_similarity

    rng = np.random.default_rng(0)
    a = rng.random((64, 64))
    b = np.clip(a + 0.1 * rng.normal(size=a.shape), 0, 1)
    ours = ssim(torch.tensor(a)[..., None], torch.tensor(b)[..., None])
    ref = structural_similarity(a, b, data_range=1.0, gaussian_weights=True, sigma=1.5,
                                use_sample_covariance=False)
    # borders differ (zero padding vs cropping): agree to a few percent
    assert float(ours) == pytest.approx(ref, rel=0.05)


def _ssim_reference(a: np.ndarray, b: np.ndarray) -> float:
    """SSIM as gs2e defines it (11-tap Gaussian window, sigma 1.5, zero padding),
    written independently with scipy's 1D correlations; a, b (..., H, W, C)."""
    from scipy.ndimage import correlate1d

    x = np.arange(11) - 5.0
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    g /= g.sum()

    def blur(v):
        v = correlate1d(v, g, axis=-2, mode="constant")
        return correlate1d(v, g, axis=-3, mode="constant")

    mx, my = blur(a), blur(b)
    sxx, syy, sxy = blur(a * a) - mx ** 2, blur(b * b) - my ** 2, blur(a * b) - mx * my
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    return float(np.mean((2 * mx * my + c1) * (2 * sxy + c2) / ((mx ** 2 + my ** 2 + c1) * (sxx + syy + c2))))


@pytest.mark.parametrize("shape", [(37, 53, 3), (2, 19, 64, 1), (12, 9, 3)])
def test_ssim_matches_reference_in_both_precisions(shape):
    # float64 runs on contiguous NCHW and float32 on the channels-last view
    # (the faster torch path of each): both must give the defined value, and a
    # gradient through either; images smaller than the window included.
    rng = np.random.default_rng(1)
    a = rng.random(shape)
    b = np.clip(a + 0.2 * rng.standard_normal(shape), 0, 1)
    ref = _ssim_reference(a, b)
    for dtype, tol in ((torch.float64, 1e-13), (torch.float32, 2e-6)):
        ta = torch.tensor(a, dtype=dtype, requires_grad=True)
        val = ssim(ta, torch.tensor(b, dtype=dtype))
        assert val.dtype == dtype
        assert float(val.detach()) == pytest.approx(ref, abs=tol)
        val.backward()
        assert ta.grad.shape == ta.shape and torch.isfinite(ta.grad).all() and ta.grad.abs().sum() > 0


def test_loss_gradient_flows():
    a = torch.rand(16, 16, 3, dtype=torch.float64, requires_grad=True)
    b = torch.rand(16, 16, 3, dtype=torch.float64)
    photometric_loss(a, b).backward()
    assert torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0


def test_psnr_value():
    a = torch.zeros(4, 4, 3)
    b = torch.full((4, 4, 3), 0.1)
    assert psnr(a, b) == pytest.approx(20.0)


def test_knn_scales():
    xyz = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5.0]])
    s = knn_log_scales(xyz, k=3)
    assert s.shape == (5, 3) and np.isclose(s[0, 0], 0.0)
    # duplicate points do not give -inf
    dup = np.zeros((4, 3))
    assert np.all(np.isfinite(knn_log_scales(dup)))


def test_init_from_points_and_bad_input():
    rng = np.random.default_rng(0)
    xyz = rng.normal(size=(100, 3))
    xyz[3] = np.nan  # dropped
    rgb = rng.integers(0, 256, size=(100, 3))
    g = init_from_points(xyz, rgb, sh_degree=2)
    assert g["sh"].shape == (99, 9, 3)
    np.testing.assert_allclose(SH_C0 * g["sh"][0, 0] + 0.5, rgb[0] / 255)
    assert np.allclose(1 / (1 + np.exp(-g["opacity_logits"])), 0.1)
    with pytest.raises(InputError, match="too few points"):
        init_from_points(xyz[:1], rgb[:1])
