"""Colour transfer: sRGB encoding <-> linear light, luminance.

Rendered 3DGS colours reproduce the sRGB-encoded training photos; physical
quantities (motion blur, the photocurrent an event pixel sees) are linear.
Arrays of any shape, values in [0, 1]: numpy arrays (float64 results) or
torch tensors (differentiable, their own dtype; what the event-based
reconstruction's losses use).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

REC709 = np.array([0.2126, 0.7152, 0.0722])
_DECODE_SEGMENTS, _DECODE_DEGREE = 64, 4


def _decode_table() -> np.ndarray:
    """(64, 5) float64: per segment [k/64, (k+1)/64] of [0, 1], the power-basis
    coefficients (in s = 64 x - k) of the degree-4 Chebyshev interpolant of
    ((x + 0.055) / 1.055)^2.4: within 1e-11 of it, 3e-9 relative, on
    [0.04045, 1] (tests/test_color.py), far below a float32 ulp."""
    from numpy.polynomial import chebyshev, polynomial

    d = _DECODE_DEGREE
    nodes = np.cos((2 * np.arange(d + 1) + 1) * np.pi / (2 * (d + 1)))  # in [-1, 1]
    tab = np.zeros((_DECODE_SEGMENTS, d + 1))
    for k in range(_DECODE_SEGMENTS):
        x = (k + (nodes + 1) / 2) / _DECODE_SEGMENTS
        c_t = chebyshev.cheb2poly(chebyshev.chebfit(nodes, ((x + 0.055) / 1.055) ** 2.4, d))
        c_s = np.zeros(d + 1)  # t = 2 s - 1
        for i, a in enumerate(c_t):
            c_s = polynomial.polyadd(c_s, a * polynomial.polypow([-1.0, 2.0], i))[:d + 1]
        tab[k] = c_s
    return tab


_DECODE_TAB = _decode_table()


@njit(inline="always", cache=True)
def srgb_decode(x):
    """One sRGB-encoded value -> linear light (float64), as
    :func:`srgb_to_linear`: exact below 0.04045, the table's polynomial on
    [0.04045, 1) (~20x cheaper than the power), the power from 1 (white is
    exactly 1)."""
    x = float(x)
    if x <= 0.04045:
        return x / 12.92
    if x >= 1.0:
        return ((x + 0.055) / 1.055) ** 2.4
    s = x * 64.0
    k = min(int(s), 63)
    s -= k
    return ((((_DECODE_TAB[k, 4] * s + _DECODE_TAB[k, 3]) * s + _DECODE_TAB[k, 2]) * s
             + _DECODE_TAB[k, 1]) * s + _DECODE_TAB[k, 0])


@njit(inline="always", cache=True)
def srgb_decode_slope(x):
    """d/dx of :func:`srgb_decode` at one sRGB-encoded value (float64): 1 /
    12.92 up to 0.04045, (2.4 / 1.055) ((x + 0.055) / 1.055)^1.4 above (the
    IEC 61966-2-1 curve, of which the decode's table is within 3e-9)."""
    x = float(x)
    if x <= 0.04045:
        return 1.0 / 12.92
    return (2.4 / 1.055) * ((x + 0.055) / 1.055) ** 1.4


@njit(cache=True, parallel=True)
def _decode_flat(x, out, clip):
    for i in prange(x.shape[0]):
        v = x[i]
        if clip:
            v = min(max(v, 0.0), 1.0)
        out[i] = srgb_decode(v)


def _is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


def srgb_to_linear(x: np.ndarray, clip: bool = False) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light in [0, 1] (IEC 61966-2-1).

    numpy: float64 result by :func:`srgb_decode` (its table within 1e-11 of the
    power; the stages decode every rendered sub-frame, where the power cost a
    third of a compositing pass at HD), in parallel; ``clip`` first clamps to
    [0, 1]. torch: the exact formula (differentiable)."""
    if _is_torch(x):
        import torch

        x = x.clamp(0.0, 1.0) if clip else x
        return torch.where(x <= 0.04045, x / 12.92, ((x.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)
    x = np.asarray(x)
    if not np.issubdtype(x.dtype, np.floating):
        x = x.astype(np.float64)
    out = np.empty(x.shape, np.float64)
    if x.size:
        _decode_flat(np.ascontiguousarray(x).reshape(-1), out.reshape(-1), clip)
    return out


def linear_to_srgb(y: np.ndarray) -> np.ndarray:
    """Linear light in [0, 1] -> sRGB-encoded values in [0, 1]."""
    if _is_torch(y):
        import torch

        y = y.clamp(0.0, 1.0)
        return torch.where(y <= 0.0031308, 12.92 * y, 1.055 * y.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)
    y = np.clip(np.asarray(y, dtype=np.float64), 0.0, 1.0)
    return np.where(y <= 0.0031308, 12.92 * y, 1.055 * np.power(np.maximum(y, 0.0031308), 1 / 2.4) - 0.055)


def luminance(linear_rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of linear RGB (..., 3) -> (...)."""
    if _is_torch(linear_rgb):
        import torch

        return linear_rgb @ torch.as_tensor(REC709, dtype=linear_rgb.dtype)
    return np.asarray(linear_rgb, dtype=np.float64) @ REC709
