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


def polarity_from_file(p: np.ndarray, where: str) -> np.ndarray:
    """uint8 polarity (1 = ON) of a file's polarity field in any of the
    conventions files use: bool, {0, 1} or signed {-1, +1} (any integer or
    float dtype; v2e and others write int8 -1/+1). Any other value cannot be
    a polarity: InputError naming ``where``, the value and how many."""
    p = np.asarray(p)
    if p.dtype == bool or p.size == 0:
        return p.astype(np.uint8)
    bad = (p != 0) & (p != 1) & (p != -1)
    if np.any(bad):
        v = p[bad]
        raise InputError(f"{where}: polarity {v[0].item()!r} in {int(bad.sum())} event(s); a polarity is 0/1 "
                         "or -1/+1")
    if np.any(p == 0) and np.any(p == -1):
        raise InputError(f"{where}: polarity holds 0, -1 and 1: not one convention (0/1 or -1/+1)")
    return (p > 0).astype(np.uint8)


def coordinates_from_file(c: np.ndarray, size: int | None, axis: str, where: str) -> np.ndarray:
    """uint16 pixel coordinates of a file's x or y field, checked: integers
    >= 0 (a negative or fractional pixel, or one past 65535, cannot be right)
    and, when the sensor's ``size`` along that axis is known, < size.
    InputError naming ``where``, the axis, how many and the extreme."""
    c = np.asarray(c)
    if c.size == 0:
        return c.astype(np.uint16)
    if not np.issubdtype(c.dtype, np.integer):
        if not np.all(np.isfinite(c)) or np.any(c != np.round(c)):
            raise InputError(f"{where}: {axis} holds non-integer pixel coordinates (dtype {c.dtype})")
    lo, hi = c.min(), c.max()
    if lo < 0:
        raise InputError(f"{where}: negative {axis} in {int((c < 0).sum())} event(s) (min {lo})")
    limit = 65536 if size is None else int(size)
    if hi >= limit:
        what = f"the sensor's {limit} px" if size is not None else "65535"
        raise InputError(f"{where}: {axis} beyond {what} in {int((c >= limit).sum())} event(s) (max {hi})")
    return c.astype(np.uint16)


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
