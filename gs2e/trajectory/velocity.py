"""Velocity profiles v(t) on normalised time t in [0, 1] and the arc-length
reparameterisation Delta s_j proportional to v(t_j) (paper appendix A).

Two interfaces:

- an expression in ``t`` (default ``0.25*sin(t)+1.1``), parsed with :mod:`ast`
  into a tree of whitelisted numpy operations -- nothing is ever ``eval``-ed;
- a speed list ``r_0..r_{L-1}`` of multipliers of the base frame rate: segment
  k of [0, 1] (length 1/L) moves at relative speed ``r_k``; neighbouring
  segments are blended by convolving the piecewise-constant profile with a
  cubic B-spline kernel of support 2*tau (tau = tau_frac / L) centred on each
  boundary. The result is C^2 (in fact C^3) and stays within [min r, max r].

Speeds are dimensionless: only their ratios matter; presets set the time scale.
"""

from __future__ import annotations

import ast
import math
from typing import Callable

import numpy as np

from gs2e.common.errors import ConfigError

MAX_EXPR_CHARS = 500

_FUNCS: dict[str, Callable] = {
    "sin": np.sin, "cos": np.cos, "tan": np.tan,
    "arcsin": np.arcsin, "arccos": np.arccos, "arctan": np.arctan,
    "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan,
    "sinh": np.sinh, "cosh": np.cosh, "tanh": np.tanh,
    "exp": np.exp, "log": np.log, "log10": np.log10, "sqrt": np.sqrt,
    "abs": np.abs, "floor": np.floor, "ceil": np.ceil,
    "min": np.minimum, "max": np.maximum, "minimum": np.minimum, "maximum": np.maximum,
    "clip": np.clip, "atan2": np.arctan2, "arctan2": np.arctan2,
}
_CONSTS = {"pi": math.pi, "e": math.e, "tau": 2 * math.pi}
_BINOPS = {ast.Add: np.add, ast.Sub: np.subtract, ast.Mult: np.multiply,
           ast.Div: np.divide, ast.Pow: np.power, ast.Mod: np.mod}
_UNOPS = {ast.USub: np.negative, ast.UAdd: np.positive}


def _compile(node: ast.AST, key: str, expr: str) -> Callable[[np.ndarray], np.ndarray]:
    """Turn a whitelisted AST node into a closure f(t) on float64 arrays."""
    if isinstance(node, ast.Expression):
        return _compile(node.body, key, expr)
    if isinstance(node, ast.Constant) and type(node.value) in (int, float):
        val = float(node.value)
        return lambda t: np.full_like(t, val)
    if isinstance(node, ast.Name):
        if node.id == "t":
            return lambda t: t
        if node.id in _CONSTS:
            val = _CONSTS[node.id]
            return lambda t: np.full_like(t, val)
        raise ConfigError(f"{key}: unknown name '{node.id}' in '{expr}' (allowed: t, "
                          f"{', '.join(sorted(_CONSTS))})")
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        op = _BINOPS[type(node.op)]
        a, b = _compile(node.left, key, expr), _compile(node.right, key, expr)
        return lambda t: op(a(t), b(t))
    if isinstance(node, ast.UnaryOp) and type(node.op) in _UNOPS:
        op = _UNOPS[type(node.op)]
        a = _compile(node.operand, key, expr)
        return lambda t: op(a(t))
    if isinstance(node, ast.Call):
        if not isinstance(node.func, ast.Name) or node.func.id not in _FUNCS:
            name = node.func.id if isinstance(node.func, ast.Name) else ast.unparse(node.func)
            raise ConfigError(f"{key}: function '{name}' is not allowed in '{expr}' "
                              f"(allowed: {', '.join(sorted(_FUNCS))})")
        if node.keywords:
            raise ConfigError(f"{key}: keyword arguments are not allowed in '{expr}'")
        fn = _FUNCS[node.func.id]
        args = [_compile(a, key, expr) for a in node.args]
        if not 1 <= len(args) <= 3:
            raise ConfigError(f"{key}: '{node.func.id}' takes 1 to 3 arguments in '{expr}'")
        return lambda t: fn(*(a(t) for a in args))
    raise ConfigError(f"{key}: '{ast.unparse(node)}' is not allowed in a velocity expression "
                      f"'{expr}' (numbers, t, + - * / ** %, and math functions only)")


def parse_velocity_expression(expr: str, key: str = "trajectory.velocity"
                              ) -> Callable[[np.ndarray], np.ndarray]:
    """Parse ``expr`` (a function of ``t``) into a vectorised v(t).

    Returns f(t: (n,) float64) -> (n,) float64. Raises ConfigError naming ``key``
    on syntax errors or any construct outside the whitelist (attributes,
    subscripts, lambdas, comparisons, names other than t/pi/e/tau ...).
    """
    if not isinstance(expr, str) or not expr.strip():
        raise ConfigError(f"{key}: velocity expression must be a non-empty string")
    if len(expr) > MAX_EXPR_CHARS:
        raise ConfigError(f"{key}: velocity expression longer than {MAX_EXPR_CHARS} characters")
    try:
        tree = ast.parse(expr.strip(), mode="eval")
    except SyntaxError as exc:
        raise ConfigError(f"{key}: cannot parse velocity expression '{expr}': {exc.msg}") from exc
    fn = _compile(tree, key, expr)

    def v(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        with np.errstate(all="ignore"):  # non-finite results are checked by the caller
            return np.broadcast_to(np.asarray(fn(t), dtype=np.float64), t.shape)

    return v


def _bspline_step(x: np.ndarray) -> np.ndarray:
    """CDF of the centred cubic B-spline kernel on [-2, 2] (a C^3 step 0 -> 1)."""
    a = np.abs(np.clip(x, -2.0, 2.0))
    left = np.where(a >= 1.0, (2.0 - a) ** 4 / 24.0,
                    (-4.0 * a + 2.0 * a ** 3 - 0.75 * a ** 4 + 2.75) / 6.0 + 1.0 / 24.0)
    return np.where(x < 0, left, 1.0 - left)


def speed_list_profile(speeds, tau_frac: float = 0.1, key: str = "trajectory.speed_list"
                       ) -> Callable[[np.ndarray], np.ndarray]:
    """v(t) from a list of L segment speeds blended at the L-1 inner boundaries.

    Parameters
    ----------
    speeds : sequence of L > 0 positive finite floats (multipliers of the base rate).
    tau_frac : half-width tau of each blending window as a fraction of the
        segment length 1/L, in (0, 0.5] so windows never overlap.
    """
    r = np.asarray(speeds, dtype=np.float64).ravel()
    if r.size == 0:
        raise ConfigError(f"{key}: speed list is empty")
    bad = ~np.isfinite(r) | (r <= 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ConfigError(f"{key}[{i}] = {r[i]}: speeds must be positive and finite")
    if not 0 < tau_frac <= 0.5:
        raise ConfigError(f"{key}: blending tau fraction must be in (0, 0.5], got {tau_frac}")
    L = r.size
    tau = tau_frac / L
    bounds = np.arange(1, L) / L
    jumps = np.diff(r)

    def v(t: np.ndarray) -> np.ndarray:
        t = np.asarray(t, dtype=np.float64)
        out = np.full(t.shape, r[0])
        for b, dr in zip(bounds, jumps):
            # kernel support [-tau, tau] <-> B-spline support [-2, 2]
            out += dr * _bspline_step((t - b) * (2.0 / tau))
        return out

    return v


def make_profile(velocity: str, speed_list: list | None = None,
                 speed_list_tau: float = 0.0) -> Callable[[np.ndarray], np.ndarray]:
    """The velocity profile of ``trajectory.velocity`` (an expression in t), or
    of ``trajectory.speed_list`` with its blending half-width
    ``speed_list_tau``, which wins if set."""
    if speed_list:
        return speed_list_profile(speed_list, speed_list_tau)
    return parse_velocity_expression(velocity)


def sample_profile(v: Callable[[np.ndarray], np.ndarray], t: np.ndarray,
                   key: str = "trajectory.velocity", n_check: int = 4097) -> np.ndarray:
    """Evaluate v at ``t`` and reject profiles that are not positive and finite on
    [0, 1] (checked at ``t`` and on a uniform grid of ``n_check`` points)."""
    grid = np.linspace(0.0, 1.0, n_check)
    for tt in (grid, t):
        u = v(tt)
        bad = ~np.isfinite(u) | (u <= 0)
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise ConfigError(f"{key}: velocity must be positive and finite on [0, 1], "
                              f"got v({tt[i]:.6g}) = {u[i]}")
        if tt is t:
            return np.asarray(u, dtype=np.float64)
    raise AssertionError("unreachable")


def reparameterise(u: np.ndarray, total: float) -> np.ndarray:
    """Target arc lengths s_j (M,) with s_0 = 0, s_{M-1} = total and
    s_{j+1} - s_j = total * u_j / sum(u_0..u_{M-2}) (paper eq. A.2).

    ``u``: (M,) speeds sampled at t_j = j/(M-1); the last one is unused.
    """
    u = np.asarray(u, dtype=np.float64)
    M = u.size
    if M < 2:
        return np.zeros(M)
    c = np.cumsum(u[:-1])
    s = np.empty(M)
    s[0] = 0.0
    s[1:] = c * (total / c[-1])
    s[-1] = total  # exact end point despite rounding
    return s
