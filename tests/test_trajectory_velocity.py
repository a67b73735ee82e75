"""Velocity profiles: safe expression parsing, speed-list blending, reparameterisation."""

import numpy as np
import pytest

from gs2e.common.errors import ConfigError
from gs2e.trajectory.velocity import (make_profile, parse_velocity_expression, reparameterise,
                                      sample_profile, speed_list_profile)


def test_default_expression_values():
    v = parse_velocity_expression("0.25*sin(t)+1.1")
    t = np.linspace(0, 1, 11)
    np.testing.assert_allclose(v(t), 0.25 * np.sin(t) + 1.1, rtol=0, atol=0)


@pytest.mark.parametrize("expr,ref", [
    ("2", lambda t: np.full_like(t, 2.0)),
    ("1 + t**2 - t % 0.5", lambda t: 1 + t ** 2 - t % 0.5),
    ("exp(-t)*cos(pi*t/4) + max(t, 0.5)", lambda t: np.exp(-t) * np.cos(np.pi * t / 4) + np.maximum(t, 0.5)),
    ("clip(t, 0.1, 0.9)", lambda t: np.clip(t, 0.1, 0.9)),
    ("-(-1.5)", lambda t: np.full_like(t, 1.5)),
])
def test_expressions(expr, ref):
    t = np.linspace(0, 1, 7)
    np.testing.assert_allclose(parse_velocity_expression(expr)(t), ref(t))


@pytest.mark.parametrize("expr", [
    "__import__('os').system('true')", "t.__class__", "(lambda x: x)(t)", "t[0]",
    "open('x')", "x + 1", "t if t else 1", "t > 0", "[t]", "sin(t, k=1)", "np.sin(t)",
    "1e9999 if 1 else 0", "", "sin(", "'abc'",
])
def test_rejects_unsafe_or_invalid(expr):
    with pytest.raises(ConfigError, match="trajectory.velocity"):
        parse_velocity_expression(expr)


@pytest.mark.parametrize("expr", ["t - 0.5", "0*t", "log(t)", "1/(t-0.5)", "sqrt(t-2)", "exp(1000*t)"])
def test_non_positive_or_non_finite_profile_rejected(expr):
    v = parse_velocity_expression(expr)
    with pytest.raises(ConfigError, match="trajectory.velocity.*positive and finite"):
        sample_profile(v, np.linspace(0, 1, 50))


def test_speed_list_blend_properties():
    r = [1.0, 3.0, 0.5, 0.5, 2.0]
    tau = 0.1
    v = speed_list_profile(r, tau)
    L = len(r)
    t = np.linspace(0, 1, 200001)
    y = v(t)
    # equals r_k away from the 2*tau windows, stays within [min r, max r]
    seg = np.minimum((t * L).astype(int), L - 1)
    dist = np.abs(t * L - np.round(t * L))  # distance to the nearest boundary, in segments
    inner = dist > tau
    np.testing.assert_allclose(y[inner], np.asarray(r)[seg[inner]], atol=1e-12)
    assert y.min() >= min(r) - 1e-12 and y.max() <= max(r) + 1e-12
    # C^2: the second difference changes by O(h) per step (a C^1-only blend,
    # e.g. a cubic smoothstep, jumps by O(max |v''|) at the window edges)
    h = t[1] - t[0]
    d2 = np.diff(y, 2) / h ** 2
    assert np.abs(np.diff(d2)).max() < 0.01 * np.abs(d2).max()
    # boundary midpoint is the average of neighbours (symmetric kernel)
    np.testing.assert_allclose(v(np.array([0.2])), [2.0], rtol=1e-12)


def test_speed_list_rejects_bad_values():
    with pytest.raises(ConfigError, match=r"trajectory.speed_list\[1\]"):
        speed_list_profile([1.0, 0.0, 2.0])
    with pytest.raises(ConfigError, match=r"trajectory.speed_list\[0\]"):
        speed_list_profile([float("nan")])
    with pytest.raises(ConfigError, match="trajectory.speed_list"):
        speed_list_profile([])


def test_make_profile_prefers_speed_list():
    v = make_profile("t - 10", [2.0], 0.1)
    np.testing.assert_allclose(v(np.array([0.3])), [2.0])


@pytest.mark.parametrize("ratio", [1.0, 1000.0])
def test_reparameterise_exact_ratios(ratio):
    M = 1001
    t = np.linspace(0, 1, M)
    u = np.where(t < 0.5, 1.0, ratio)
    s = reparameterise(u, 7.5)
    assert s[0] == 0.0 and s[-1] == 7.5
    ds = np.diff(s)
    expect = 7.5 * u[:-1] / u[:-1].sum()
    np.testing.assert_allclose(ds, expect, rtol=1e-10)
    assert np.all(ds > 0)
