"""SSIM/PSNR losses and SfM-point initialisation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gs2e.common.errors import InputError
from gs2e.splat.init import SH_C0, init_from_points, knn_log_scales
from gs2e.splat.loss import photometric_loss, psnr, ssim, ssim_reference


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


@pytest.mark.parametrize("shape", [(37, 53, 3), (2, 19, 64, 1), (12, 9, 3), (1, 1, 3)])
@pytest.mark.parametrize("dtype,rtol", [(torch.float64, 1e-10), (torch.float32, 2e-3)])
def test_ssim_gradient_in_closed_form_matches_autograd(shape, dtype, rtol):
    """The CPU SSIM (OpenCV blurs, closed-form gradient) against torch's autograd
    through its own convolutions (ssim_reference): the value, and the gradient
    of both images where both need one, on images smaller than the window and
    on a single pixel; flat regions (equal images there) included, where the
    variances vanish and only C2 keeps the quotient finite."""
    rng = np.random.default_rng(2)
    a = rng.random(shape)
    b = np.clip(a + 0.2 * rng.standard_normal(shape), 0, 1)
    b[..., : shape[-2] // 2, :] = a[..., : shape[-2] // 2, :]  # half the image identical
    a[..., :3, :3, :] = 0.5  # and a flat patch
    grads = []
    for fn in (ssim, ssim_reference):
        ta = torch.tensor(a, dtype=dtype, requires_grad=True)
        tb = torch.tensor(b, dtype=dtype, requires_grad=True)
        val = fn(ta, tb)
        (3.0 * val).backward()
        grads.append((float(val.detach()), ta.grad, tb.grad))
    (v, ga, gb), (v_ref, ga_ref, gb_ref) = grads
    assert v == pytest.approx(v_ref, rel=1e-12 if dtype == torch.float64 else 1e-6)
    for g, g_ref in ((ga, ga_ref), (gb, gb_ref)):
        assert g.dtype == dtype and g.shape == g_ref.shape
        scale = float(g_ref.abs().max())
        assert scale > 0 and float((g - g_ref).abs().max()) <= rtol * scale


def test_ssim_gradient_passes_gradcheck():
    g = torch.Generator().manual_seed(3)
    a = torch.rand(9, 14, 2, generator=g, dtype=torch.float64, requires_grad=True)
    b = torch.rand(9, 14, 2, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(ssim, (a, b))
    # only one input needing a gradient: the other gets none
    a2 = a.detach().clone().requires_grad_(True)
    ssim(a2, b.detach()).backward()
    assert a2.grad is not None and torch.isfinite(a2.grad).all()


def test_ssim_is_the_same_bits_at_any_thread_count():
    import cv2

    rng = np.random.default_rng(4)
    a = torch.tensor(rng.random((120, 161, 3)), dtype=torch.float32, requires_grad=True)
    b = torch.tensor(rng.random((120, 161, 3)), dtype=torch.float32)
    import numba

    before, before_nb = cv2.getNumThreads(), numba.get_num_threads()
    out = []
    try:
        for n in (1, 2, 4):
            cv2.setNumThreads(n)
            numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
            a.grad = None
            v = ssim(a, b)
            v.backward()
            out.append((v.detach().clone(), a.grad.clone()))
    finally:
        cv2.setNumThreads(before)
        numba.set_num_threads(before_nb)
    assert all(torch.equal(o[0], out[0][0]) and torch.equal(o[1], out[0][1]) for o in out)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_ssim_fused_map_is_torchs_elementwise_arithmetic(dtype):
    """The fused per-pixel loop computes the SSIM map from the five blurs with
    the operations of ssim_reference in their order: the same bits as torch's
    elementwise ops (no contraction into fused multiply-adds), also where
    the variances cancel (flat regions, mu^2 close to blur(x^2))."""
    from gs2e.splat import loss as L

    g = torch.Generator().manual_seed(5)
    x = torch.rand(1, 40, 57, 3, generator=g, dtype=dtype)
    x[:, :20] = 0.25  # flat: sigma^2 cancels to rounding
    y = (x * 0.7 + 0.1 * torch.rand(x.shape, generator=g, dtype=dtype)).contiguous()
    mu_x, mu_y, bxx, byy, bxy = L._blur_hwc([x, y, x * x, y * y, x * y], 11, 1.5)
    a1, a2 = 2 * mu_x * mu_y + L.C1, 2 * (bxy - mu_x * mu_y) + L.C2
    b1, b2 = mu_x * mu_x + mu_y * mu_y + L.C1, (bxx - mu_x * mu_x) + (byy - mu_y * mu_y) + L.C2
    want = a1 * a2 / (b1 * b2)
    got = torch.empty(x.shape, dtype=dtype)
    c1, c2 = (np.dtype(str(dtype).split(".")[1]).type(c) for c in (L.C1, L.C2))
    L._ssim_map(*(t.numpy().reshape(-1) for t in (mu_x, mu_y, bxx, byy, bxy)), c1, c2,
                got.numpy().reshape(-1))
    assert torch.equal(got, want)


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
