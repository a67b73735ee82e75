"""Checks and conversions of the event conventions (see :mod:`gs2e.export`).

Every function that takes events from outside (a file, a caller) or hands
them to another layout goes through these, so a wrong polarity encoding or
time unit fails with a message naming where it came from instead of
silently producing a mirrored or shifted dataset.
"""

from __future__ import annotations

import numpy as np

from gs2e.common.errors import InputError

POLARITY_ON = 1   # gs2e files: 1 = ON (brightness increase)
POLARITY_OFF = 0  # gs2e files: 0 = OFF

# tonic's field names; t int64 us, p int8 in {0, 1} (tonic's ToVoxelGrid rewrites
# p == 0 to -1 in place, which a bool field could not hold).
TONIC_DTYPE = np.dtype([("x", "<i2"), ("y", "<i2"), ("t", "<i8"), ("p", "<i1")])


def check_polarity01(p: np.ndarray, where: str) -> np.ndarray:
    """``p`` as uint8 after checking that every value is 0 (OFF) or 1 (ON)."""
    p = np.asarray(p)
    if p.size and (p.min() < 0 or p.max() > 1):
        raise InputError(f"{where}: polarity must be 0 (OFF) or 1 (ON), found values in "
                         f"[{p.min()}, {p.max()}] (signed -1/+1 data must be converted first)")
    return p.astype(np.uint8, copy=False)


def signed_polarity(p: np.ndarray, where: str) -> np.ndarray:
    """{0, 1} -> int8 {-1, +1} (OFF -> -1, ON -> +1), checking the input."""
    return check_polarity01(p, where).astype(np.int8) * 2 - 1


def check_times_us(t: np.ndarray, where: str) -> np.ndarray:
    """``t`` as int64 microseconds after checking the dtype and the order."""
    t = np.asarray(t)
    if not np.issubdtype(t.dtype, np.integer):
        raise InputError(f"{where}: event times must be integer microseconds, got dtype {t.dtype}")
    t = t.astype(np.int64, copy=False)
    if t.size > 1 and np.any(np.diff(t) < 0):
        raise InputError(f"{where}: event times are not sorted")
    return t


def check_events_in_sensor(x: np.ndarray, y: np.ndarray, width: int, height: int, where: str) -> None:
    """Every event lies on the (width, height) sensor."""
    if len(x) and (int(np.max(x)) >= width or int(np.max(y)) >= height):
        raise InputError(f"{where}: events outside the {width}x{height} sensor "
                         f"(max x {int(np.max(x))}, max y {int(np.max(y))})")


def to_tonic(t_us: np.ndarray, x: np.ndarray, y: np.ndarray, p: np.ndarray, where: str) -> np.ndarray:
    """Structured array with tonic's fields x, y, t (int64 us), p ({0, 1})."""
    out = np.empty(len(t_us), TONIC_DTYPE)
    out["x"], out["y"] = x, y
    out["t"] = check_times_us(t_us, where)
    out["p"] = check_polarity01(p, where)
    return out
