"""The non-finite guard of rendering and training: NaN/inf in a parameter,
camera value or gradient is an error naming it, raised where it is found
(the CPU rasterizer and the gsplat backend both check with these)."""

from __future__ import annotations

import math

import numpy as np
import torch

from gs2e.common.errors import InputError


class NonFiniteError(InputError):
    """A parameter, camera value or gradient holds NaN/inf (message names it)."""


def all_finite(x: torch.Tensor | np.ndarray) -> bool:
    """Whether every value is finite. A finite float64 sum means they all are
    (NaN and inf propagate): one pass and no mask, a fifth of the cost on a
    training step's tensors; the elementwise test runs only when it is not."""
    if isinstance(x, torch.Tensor):
        x = x.detach()
        return (x.numel() == 0 or math.isfinite(float(x.sum(dtype=torch.float64)))
                or bool(torch.isfinite(x).all()))
    with np.errstate(over="ignore", invalid="ignore"):  # inf/NaN sums are the signal
        total = float(x.sum(dtype=np.float64)) if x.size else 0.0
    return math.isfinite(total) or bool(np.isfinite(x).all())


def check_finite(name: str, x: torch.Tensor) -> None:
    """Raise NonFiniteError if ``x`` holds NaN/inf, naming the tensor and rows."""
    if all_finite(x):
        return
    bad = ~torch.isfinite(x)
    if bool(bad.any()):
        rows = torch.nonzero(bad.reshape(x.shape[0], -1).any(dim=1) if x.dim() else bad.reshape(1))
        first = rows[:5].flatten().tolist()
        raise NonFiniteError(f"{name} holds {int(bad.sum())} non-finite value(s) "
                             f"(NaN/inf) at rows {first}{'...' if rows.shape[0] > 5 else ''}")
