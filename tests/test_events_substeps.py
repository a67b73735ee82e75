"""Points between renders on a cubic (events.sampling.substeps, issue 67)."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.common.errors import ConfigError
from gs2e.config import load_config
from gs2e.events.rendered import cubic_substeps

EPS = 1e-3


def _signal(t_us):
    """A smooth luminance (2 pixels) in time: log(L + eps) = sinusoids."""
    t = np.asarray(t_us, np.float64)[..., None, None] * 1e-6
    g = np.concatenate([np.sin(40 * t), 0.5 * np.cos(25 * t) - 1.0], axis=-1)
    return (np.exp(g) - EPS).astype(np.float32)


def _run(h_us: int, k: int, n: int = 40):
    times = np.arange(n + 1) * h_us + 1000
    frames = [(int(t), _signal(t)) for t in times]
    return list(cubic_substeps(iter(frames[1:]), k, EPS, frames[0])), frames


def test_renders_pass_unchanged_and_points_fall_between_them():
    out, frames = _run(1000, 4)
    ts = [t for t, _ in out]
    assert ts == sorted(set(ts)) and all(isinstance(t, int) for t in ts)
    assert len(out) == 4 * (len(frames) - 1)
    kept = {t: f for t, f in out}
    for t, f in frames[1:]:
        assert kept[t] is f  # the render itself, not a round trip through log and exp


def test_cubic_error_falls_as_h_cubed_and_beats_a_line():
    errs = {}
    for h in (4000, 2000, 1000):
        out, _ = _run(h, 4, n=int(40 * 1000 / h))
        mid = [(t, f) for t, f in out if (t - 1000) % h]
        g = np.array([np.log(f.astype(np.float64) + EPS) for _, f in mid])
        truth = np.array([np.log(_signal(t).astype(np.float64) + EPS) for t, _ in mid])
        # a line through the renders at the same times
        t = np.array([t for t, _ in mid], np.float64)
        t0 = 1000 + np.floor((t - 1000) / h) * h
        s = ((t - t0) / h)[:, None, None]
        line = (1 - s) * np.log(_signal(t0).astype(np.float64) + EPS) + s * np.log(
            _signal(t0 + h).astype(np.float64) + EPS)
        errs[h] = (np.abs(g - truth).mean(), np.abs(line - truth).mean())
    cubic_slope = np.log2(errs[2000][0] / errs[1000][0])
    assert cubic_slope > 2.5, errs
    assert all(c < 0.2 * lin for c, lin in errs.values()), errs


def test_steps_shorter_than_the_points_skip_duplicates():
    out, frames = _run(2, 8, n=5)
    ts = [t for t, _ in out]
    assert ts == sorted(set(ts)) and set(t for t, _ in frames[1:]) <= set(ts)


def test_substeps_need_a_whole_image_mode():
    from gs2e.config import check_config

    with pytest.raises(ConfigError, match="substeps"):
        check_config(load_config({"events": {"sampling": {"mode": "tile", "substeps": 4}}}))
