"""Colour transfer: sRGB encoding <-> linear light, luminance.

Rendered 3DGS colours reproduce the sRGB-encoded training photos; physical
quantities (motion blur, the photocurrent an event pixel sees) are linear.
Arrays of any shape, values in [0, 1]: numpy arrays (float64 results) or
torch tensors (differentiable, their own dtype; what the event-based
reconstruction's losses use).
"""

from __future__ import annotations

import numpy as np

REC709 = np.array([0.2126, 0.7152, 0.0722])


def _is_torch(x) -> bool:
    return type(x).__module__.startswith("torch")


def srgb_to_linear(x: np.ndarray) -> np.ndarray:
    """sRGB-encoded values in [0, 1] -> linear light in [0, 1] (IEC 61966-2-1)."""
    if _is_torch(x):
        import torch

        return torch.where(x <= 0.04045, x / 12.92, ((x.clamp_min(0.04045) + 0.055) / 1.055) ** 2.4)
    x = np.asarray(x, dtype=np.float64)
    return np.where(x <= 0.04045, x / 12.92, ((np.maximum(x, 0.04045) + 0.055) / 1.055) ** 2.4)


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
