"""sRGB decoding by table: against the exact power law, at the branch point, out of
range, in every dtype and shape the stages pass, and the luminance the event stage
computes from it."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.common.color import REC709, linear_to_srgb, srgb_to_linear


def _exact(x):
    x = np.asarray(x, np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


def test_table_decode_matches_the_power_law_to_far_below_float32():
    x = np.linspace(0.0, 1.0, 2_000_001)
    x = np.concatenate([x, np.nextafter(0.04045, [0.0, 1.0]), [0.04045, 1.0, 1.0 - 2**-40],
                        np.arange(65) / 64.0, np.nextafter(np.arange(1, 65) / 64.0, 0.0)])
    got, ref = srgb_to_linear(x), _exact(x)
    assert np.abs(got - ref).max() < 1e-11
    hi = x > 0.04045
    assert (np.abs(got - ref)[hi] / ref[hi]).max() < 5e-9
    lo = x <= 0.04045
    assert np.array_equal(got[lo], ref[lo])  # the linear branch is exact
    # every float32 value in [0, 1] decodes within 0.1 ulp of float32 at the result
    x32 = np.linspace(0, 1, 300_001, dtype=np.float32)
    d = np.abs(srgb_to_linear(x32) - _exact(x32))
    assert np.all(d <= 0.1 * np.spacing(_exact(x32).astype(np.float32)) + 1e-300)
    # monotone, as the power law (no step down at segment joints)
    assert np.all(np.diff(srgb_to_linear(np.linspace(0.04, 1.0, 1_000_001))) > 0)


def test_out_of_range_shapes_dtypes_and_clip():
    x = np.array([-0.5, -0.0, 1.0, 1.5, 3.0, np.inf, np.nan])  # white: exactly 1
    np.testing.assert_array_equal(srgb_to_linear(x), _exact(x))  # outside [0, 1]: the formula
    np.testing.assert_array_equal(srgb_to_linear(x, clip=True)[:5], _exact(np.clip(x[:5], 0, 1)))
    for shape in [(), (5,), (4, 3), (2, 3, 3), (0, 3), (2, 0)]:
        a = np.random.default_rng(1).random(shape)
        out = srgb_to_linear(a)
        assert out.shape == a.shape and out.dtype == np.float64
        np.testing.assert_allclose(out, _exact(a), rtol=0, atol=1e-11)
    u8 = np.arange(256, dtype=np.uint8)
    np.testing.assert_allclose(srgb_to_linear(u8 / 255.0), _exact(u8 / 255.0), rtol=0, atol=1e-11)
    # non-contiguous input
    a = np.random.default_rng(2).random((6, 8, 3))[:, ::2]
    np.testing.assert_allclose(srgb_to_linear(a), _exact(a), rtol=0, atol=1e-11)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(np.linspace(0, 1, 1001))),
                               np.linspace(0, 1, 1001), atol=1e-10)


def test_torch_path_stays_exact_and_differentiable():
    torch = pytest.importorskip("torch")
    x = torch.linspace(-0.1, 1.2, 101, dtype=torch.float64, requires_grad=True)
    y = srgb_to_linear(x)
    np.testing.assert_allclose(y.detach().numpy(), _exact(x.detach().numpy()), rtol=1e-15, atol=0)
    y.sum().backward()
    assert torch.isfinite(x.grad).all()
    yc = srgb_to_linear(x.detach(), clip=True)
    np.testing.assert_allclose(yc.numpy(), _exact(np.clip(x.detach().numpy(), 0, 1)), rtol=1e-15, atol=0)


def test_event_luminance_uses_the_same_decode():
    from gs2e.events.sampling import image_luminance

    img = np.random.default_rng(3).random((37, 45, 3)).astype(np.float32) * 1.2 - 0.1
    out = np.empty((37, 45), np.float32)
    image_luminance(img, out)
    ref = (_exact(np.clip(img.astype(np.float64), 0, 1)) @ REC709).astype(np.float32)
    d = np.abs(out.astype(np.float64) - ref)
    assert np.all(d <= np.spacing(ref))  # at most one float32 rounding apart
    assert (d > 0).mean() < 1e-3
