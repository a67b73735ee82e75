"""The continuous trajectory object and the builders of base and mini trajectories.

A :class:`Trajectory` maps a time t (microseconds) to a camera-to-world pose
through three C^1 (or smoother) maps, all stored so that it can be rebuilt
from its file:

    t_us --(cubic Hermite through (t_us_j, s_j), monotone per interval)--> s   (arc length)
    s    --(inverse arc-length table, monotone Hermite)-----> u   (curve parameter)
    u    --(pose curve, piecewise polynomial)---------------> (T, q) -> c2w

At the sample times t_us_j it returns exactly the stored poses c2w_j.
s rises along a one-way path; a path travelled back and forth
(:func:`back_and_forth`) runs it down again on its return legs.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from gs2e.common.errors import ConfigError, InputError
from gs2e.common.so3 import geodesic_angle
from gs2e.trajectory import kernels
from gs2e.trajectory.curve import (ArcTable, PoseCurve, arc_length_table, check_c2w,
                                   fit_bezier, fit_curve, hermite_eval, monotone_slopes,
                                   pose_deltas, smooth_poses, split_c2w, translation_scale)
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.velocity import reparameterise, sample_profile

MIN_QUAT_NORM = 0.05  # below this the normalised quaternion curve is ill-defined
DUP_TOL = 1e-9        # relative to the path length: shorter steps are duplicate poses
MAX_SAMPLES = 10_000_000  # poses of a back-and-forth trajectory (1.3 GB of c2w)


def fixed_times_us(t0_us: int, t1_us: int, fps: float) -> np.ndarray:
    """Times at ``fps`` from t0 to t1 (t1 included), rounded to integer us."""
    n = int(math.floor((t1_us - t0_us) * fps / 1e6 + 1e-9)) + 1
    t = np.round(t0_us + np.arange(n) * 1e6 / fps).astype(np.int64)
    if t[-1] < t1_us:
        t = np.append(t, np.int64(t1_us))
    return t


def eval_at_s(curve: PoseCurve, arc: ArcTable, s: np.ndarray) -> np.ndarray:
    """Poses (Q, 4, 4) at arc lengths s (Q,) (compiled kernel)."""
    s = np.ascontiguousarray(s, dtype=np.float64)
    out = np.empty((s.shape[0], 4, 4))
    kernels.eval_poses(s, arc.L, arc.u, arc.du, curve.breaks, curve.coeffs_t, out)
    return out


@dataclass
class Trajectory:
    """A timed camera path, evaluable at any time in [t_us[0], t_us[-1]].

    Attributes
    ----------
    curve : pose curve over u.
    arc : inverse arc-length map s -> u.
    t_us : (M,) int64 sample times, strictly increasing, microseconds.
    s : (M,) float64 arc length at each sample time (metric units).
    ds_dt : (M,) slopes of the time map, arc length per microsecond.
    c2w : (M, 4, 4) float64 poses at t_us (OpenCV camera axes).
    K : (3, 3) pinhole intrinsics (pixels); width, height in pixels.
    meta : JSON-serialisable description (kind, method, preset, speeds ...).
    """

    curve: PoseCurve
    arc: ArcTable
    t_us: np.ndarray
    s: np.ndarray
    ds_dt: np.ndarray
    c2w: np.ndarray
    K: np.ndarray
    width: int
    height: int
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def duration_us(self) -> int:
        return int(self.t_us[-1] - self.t_us[0])

    @property
    def length(self) -> float:
        """Total metric arc length travelled (alpha*rad + beta*translation/scale);
        a path travelled back and forth counts every leg."""
        d = np.diff(self.s)
        if np.all(d >= 0):
            return float(self.s[-1] - self.s[0])
        return float(np.abs(d).sum())

    @functools.cached_property
    def turns_us(self) -> np.ndarray:
        """(K,) int64 sample times where the camera reverses along its path
        (the ends of a back-and-forth path's legs, :func:`back_and_forth`);
        found once per trajectory (the render stage asks for every frame)."""
        d = np.diff(self.s)
        moving = np.flatnonzero(d != 0)  # a step of zero length turns nothing
        sign = np.sign(d[moving])
        return self.t_us[moving[:-1][sign[:-1] != sign[1:]] + 1]

    def monotone_spans(self, t0_us: float, t1_us: float) -> np.ndarray:
        """(K + 2,) float64 times t0, the turns strictly inside (t0, t1), t1: within
        each span the camera moves one way along its path, so the image motion
        between a span's ends is the motion over it (a turn inside an interval
        would hide the way out and back)."""
        turns = self.turns_us.astype(np.float64)
        inside = turns[(turns > t0_us) & (turns < t1_us)]
        return np.concatenate([[float(t0_us)], inside, [float(t1_us)]])

    def arc_length_at(self, t_us: np.ndarray) -> np.ndarray:
        """Arc length s(t) (Q,) at times t_us (Q,) (float or int microseconds)."""
        t = np.ascontiguousarray(np.atleast_1d(t_us), dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"times must be 1-D, got shape {t.shape}")
        if not np.all(np.isfinite(t)):
            raise ValueError("pose_at: times must be finite")
        lo, hi = float(self.t_us[0]), float(self.t_us[-1])
        if t.size and (t.min() < lo or t.max() > hi):
            raise ValueError(f"pose_at: times must lie in [{lo:.0f}, {hi:.0f}] us, "
                             f"got [{t.min():.6g}, {t.max():.6g}]")
        out = np.empty_like(t)
        tx = self.t_us.astype(np.float64)
        if len(tx) < 2:
            out[:] = self.s[0]
            return out
        kernels.map_times(t, tx, self.s, self.ds_dt, out)
        return out

    def pose_at(self, t_us: np.ndarray) -> np.ndarray:
        """Camera-to-world poses (Q, 4, 4) at times t_us (Q,) microseconds.

        Vectorised and compiled; sorted queries are fastest. Raises ValueError
        for times outside the trajectory or non-finite times.
        """
        return eval_at_s(self.curve, self.arc, self.arc_length_at(t_us))

    # -- serialisation: everything needed to rebuild the object, as plain arrays
    def to_arrays(self) -> dict[str, np.ndarray]:
        return {
            "c2w": self.c2w, "K": self.K, "width": np.int64(self.width),
            "height": np.int64(self.height), "t_us": self.t_us.astype(np.int64),
            "s": self.s, "ds_dt": self.ds_dt,
            "curve_breaks": self.curve.breaks, "curve_coeffs": self.curve.coeffs,
            "arc_L": self.arc.L, "arc_u": self.arc.u, "arc_du": self.arc.du,
            "meta_json": np.array(json.dumps(self.meta, sort_keys=True)),
        }

    @classmethod
    def from_arrays(cls, d: dict[str, np.ndarray]) -> "Trajectory":
        return cls(
            curve=PoseCurve(np.asarray(d["curve_breaks"], np.float64),
                            np.asarray(d["curve_coeffs"], np.float64)),
            arc=ArcTable(np.asarray(d["arc_L"], np.float64), np.asarray(d["arc_u"], np.float64),
                         np.asarray(d["arc_du"], np.float64)),
            t_us=np.asarray(d["t_us"], np.int64), s=np.asarray(d["s"], np.float64),
            ds_dt=np.asarray(d["ds_dt"], np.float64), c2w=np.asarray(d["c2w"], np.float64),
            K=np.asarray(d["K"], np.float64), width=int(d["width"]), height=int(d["height"]),
            meta=json.loads(str(d["meta_json"])),
        )


# ---------------------------------------------------------------- path construction

@dataclass
class SampledPath:
    """A fitted, sampled (untimed) path: curve, arc map, sample arc lengths, poses."""

    curve: PoseCurve
    arc: ArcTable
    s: np.ndarray          # (M,) arc length of each sample
    c2w: np.ndarray        # (M, 4, 4)
    knot_index: np.ndarray  # (n_knots,) index of the input pose behind each curve knot
    info: dict[str, Any]


def _dedupe(delta: np.ndarray) -> np.ndarray:
    """Indices of poses to keep: a pose whose step from the previous kept pose is
    below DUP_TOL of the whole length duplicates it (zero-length segment)."""
    total = float(delta.sum())
    # the metric is in radians / translation scales, so 1e-12 is rounding noise
    keep = np.concatenate([[True], delta > max(DUP_TOL * total, 1e-12)])
    return np.flatnonzero(keep)


def fit_path_curve(c2w: np.ndarray, alpha: float, beta_n: float, method: str,
                   bezier_degree: int | None = None) -> tuple[PoseCurve, ArcTable, np.ndarray]:
    """Curve through (or, for a Bezier of given degree, near) keyframes ``c2w``
    parameterised by their cumulative displacement; returns the curve, its arc
    map and the indices of the keyframes kept (duplicates dropped)."""
    delta = pose_deltas(c2w, alpha, beta_n)
    keep = _dedupe(delta)
    T, q = split_c2w(c2w[keep])
    u = np.concatenate([[0.0], np.cumsum(pose_deltas(c2w[keep], alpha, beta_n))])
    if bezier_degree is not None and len(keep) > 2:
        curve = fit_bezier(u, T, q, bezier_degree)
    else:
        curve = fit_curve(u, T, q, method)
    arc = arc_length_table(curve, alpha, beta_n)
    if arc.min_quat_norm < MIN_QUAT_NORM:
        raise InputError(f"rotation curve degenerates (quaternion norm {arc.min_quat_norm:.3g}); "
                         "the input has rotations that alternate by about 180 degrees")
    return curve, arc, keep


def build_base_path(c2w_in: np.ndarray, cfg: TrajectorySettings, profile: Callable[[np.ndarray], np.ndarray],
                    what: str = "poses") -> SampledPath:
    """Smoothing + velocity-controlled dense interpolation (paper section 3.4.1).

    Parameters
    ----------
    c2w_in : (N, 4, 4) input camera-to-world poses, in sequence order.
    cfg : the ``trajectory`` config section (smooth_half_width, gamma, alpha,
        beta, normalize_translation, interpolation).
    profile : v(t) on [0, 1] (see :mod:`gs2e.trajectory.velocity`).
    """
    P = check_c2w(c2w_in, what)
    N = len(P)
    sm = smooth_poses(P, int(cfg.smooth_half_width))
    scale = translation_scale(sm) if cfg.normalize_translation else 1.0
    alpha, beta_n = float(cfg.alpha), float(cfg.beta) / scale
    curve, arc, keep = fit_path_curve(sm, alpha, beta_n, cfg.interpolation)
    M = max(2, math.ceil(float(cfg.gamma) * N - 1e-9))
    t = np.linspace(0.0, 1.0, M)
    v = sample_profile(profile, t, "trajectory.speed_list" if cfg.speed_list
                       else "trajectory.velocity")
    s = reparameterise(v, arc.total)
    dense = eval_at_s(curve, arc, s)
    info = {"n_input": N, "n_knots": int(len(keep)), "n_poses": M, "translation_scale": scale,
            "alpha": alpha, "beta_per_scene_unit": beta_n,
            "length_discrete": float(pose_deltas(sm, alpha, beta_n).sum()),
            "length_curve": arc.total, "v": v}
    return SampledPath(curve, arc, s, dense, keep, info)


def points_in_view_fraction(points_w: np.ndarray, c2w: np.ndarray, K: np.ndarray, width: int,
                            height: int, near: float = 1e-3) -> np.ndarray:
    """(M,) fraction of the scene points each pose sees: in front of the camera
    (z > ``near``, scene units) and projected inside the ``width`` x ``height``
    image. points_w : (P, 3); c2w : (M, 4, 4); K : (3, 3)."""
    from gs2e.common.motion import project_points

    out = np.empty(len(c2w))
    for j, T in enumerate(c2w):
        uv, z = project_points(points_w, T, K, near)
        out[j] = np.mean((z > near) & (uv[:, 0] >= 0) & (uv[:, 0] < width) & (uv[:, 1] >= 0)
                         & (uv[:, 1] < height))
    return out


def build_mini_paths(base: SampledPath, cfg: TrajectorySettings, rng: np.random.Generator, alpha: float,
                     beta_n: float, sees: Callable[[np.ndarray], np.ndarray] | None = None,
                     min_sees: float = 0.0, max_draws: int = 100) -> list[tuple[SampledPath, int]]:
    """Novel-view mini-trajectories (paper section 3.4.2).

    G groups of K keyframes are drawn without replacement from the dense base
    poses (all G*K distinct when M >= G*K, else distinct within a group), or,
    with ``mini_window`` < 1, each group from a random stretch covering that
    fraction of the base poses (keeps novel views near the input ones); sorted
    by path order; each group is fitted by a cubic B-spline or a least-squares
    Bezier of random degree d in ``mini_degrees`` (capped at K-1) over its local
    cumulative displacement, and sampled at F poses uniform in true arc length.

    With ``sees`` (poses (F, 4, 4) -> (F,) fraction of the scene each sees), a
    group whose path has a pose seeing less than ``min_sees`` is drawn again
    (same curve family and degree), up to ``max_draws`` draws: keyframes from
    far apart on a ring of views join through the object or look past it.
    Returns (path, index of the group's first keyframe in the base path).
    """
    G, K, F = int(cfg.mini_groups), int(cfg.mini_keyframes), int(cfg.mini_frames)
    M = len(base.c2w)
    if G == 0:
        return []
    if M < K:
        raise InputError(f"mini-trajectories need at least mini_keyframes={K} base poses, got {M}")
    window = float(cfg.mini_window)
    W = min(M, max(K, int(round(window * M))))

    def draw() -> np.ndarray:
        """One group's keyframes: from anywhere on the base path (the paper), or
        from a random stretch of it (stays near the input views)."""
        if window >= 1.0:
            return rng.choice(M, size=K, replace=False)
        return rng.integers(0, M - W + 1) + rng.choice(W, size=K, replace=False)

    if window >= 1.0 and M >= G * K:  # all G*K keyframes distinct
        groups = rng.choice(M, size=G * K, replace=False).reshape(G, K)
    else:
        groups = np.stack([draw() for _ in range(G)])

    def fit(idx: np.ndarray, use_bspline: bool, degree: int):
        kf = base.c2w[idx]
        try:
            curve, arc, keep = fit_path_curve(kf, alpha, beta_n, "bspline",
                                              None if use_bspline else degree)
            method = "bspline" if use_bspline else "bezier"
        except InputError:
            if use_bspline:
                raise
            # a least-squares Bezier through widely spread rotations can pass near
            # the quaternion origin; the interpolating spline cannot
            curve, arc, keep = fit_path_curve(kf, alpha, beta_n, "bspline")
            method = "bspline (bezier fallback)"
        s = np.linspace(0.0, arc.total, F)
        return curve, arc, keep, method, s, eval_at_s(curve, arc, s)

    out = []
    for g in range(G):
        idx = np.sort(groups[g])
        use_bspline = rng.random() < float(cfg.mini_bspline_probability)
        degree = int(rng.choice(np.asarray(cfg.mini_degrees, dtype=np.int64)))
        curve, arc, keep, method, s, c2w = fit(idx, use_bspline, degree)
        draws, seen = 1, None
        if sees is not None:
            seen = float(sees(c2w).min())
            while seen < min_sees and draws < max_draws:
                idx = np.sort(draw())
                curve, arc, keep, method, s, c2w = fit(idx, use_bspline, degree)
                seen, draws = float(sees(c2w).min()), draws + 1
            if seen < min_sees:
                raise InputError(
                    f"mini-trajectory {g}: none of {max_draws} draws keeps the scene in view (the last "
                    f"sees {seen:.0%} of the points at worst, need {min_sees:.0%}); lower trajectory.mini_window "
                    f"or trajectory.mini_min_view")
        info = {"keyframes": idx.tolist(), "method": method, "draws": draws,
                "min_points_in_view": seen,
                "degree": 3 if method.startswith("bspline") else int(min(degree, len(keep) - 1)),
                "degree_drawn": degree, "n_poses": F, "length_curve": arc.total,
                "v": np.ones(F)}
        out.append((SampledPath(curve, arc, s, c2w, keep, info), int(idx[0])))
    return out


def image_steps_width(c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                      points_w: np.ndarray) -> np.ndarray:
    """(M-1,) image motion between consecutive poses of a path, in image widths:
    per step, the median displacement of the scene points in view (the
    typical point, as a blurred frame shows it)."""
    from gs2e.common.motion import pixel_motion_px

    return np.array([pixel_motion_px(points_w, c2w[j], c2w[j + 1], K, width, height, 50.0)
                     for j in range(len(c2w) - 1)]) / float(width)


def preset_duration_s(c2w: np.ndarray, preset: dict, scale: float, fps_base: float,
                      image_steps_w: np.ndarray | None = None) -> float:
    """Duration (s) of a path sampled at uniform times.

    With ``image_steps_w`` (the path's per-step image motion in widths, from
    :func:`image_steps_width`) and the preset's ``image_speed_width_s``: the
    median over the path of the typical scene point's image speed is that
    many image widths per second, so blur and event rates match across
    scenes and sensors. Otherwise (a scene without sparse points) the peak
    frame-to-frame angular speed is ``max_angular_speed_deg_s`` or the peak
    linear speed is ``max_linear_speed_scale_s`` (translation scales per
    second), whichever is binding. A static path lasts one base frame per pose."""
    M = len(c2w)
    if M < 2:
        return 0.0
    if image_steps_w is not None and preset.get("image_speed_width_s"):
        d = float(np.median(image_steps_w)) * (M - 1) / float(preset["image_speed_width_s"])
    else:
        ang = geodesic_angle(c2w[:-1, :3, :3], c2w[1:, :3, :3]) * (M - 1)  # rad per unit t
        lin = np.linalg.norm(np.diff(c2w[:, :3, 3], axis=0), axis=1) / scale * (M - 1)
        d = max(float(ang.max()) / math.radians(float(preset["max_angular_speed_deg_s"])),
                float(lin.max()) / float(preset["max_linear_speed_scale_s"]))
    if not d > 0:
        d = (M - 1) / float(fps_base)
    return d


def timestamps_us(duration_s: float, M: int) -> np.ndarray:
    """(M,) int64 uniform timestamps from 0 to the duration, strictly increasing
    (durations shorter than M-1 microseconds are stretched to M-1)."""
    d_us = max(int(round(duration_s * 1e6)), M - 1)
    return np.round(np.linspace(0.0, float(d_us), M)).astype(np.int64)


def timed_trajectory(path: SampledPath, t_us: np.ndarray, K: np.ndarray, width: int, height: int,
                     meta: dict[str, Any]) -> Trajectory:
    """Attach timestamps to a sampled path; the time map is a monotone C^1 Hermite
    interpolant through (t_us_j, s_j) so pose_at(t_us_j) == c2w_j."""
    t = t_us.astype(np.float64)
    ds_dt = monotone_slopes(t, path.s) if len(t) >= 2 else np.zeros(len(t))
    return Trajectory(path.curve, path.arc, t_us, path.s.copy(), ds_dt, path.c2w, K,
                      width, height, meta)


def back_and_forth(traj: Trajectory, min_duration_us: int) -> Trajectory:
    """``traj`` travelled back and forth until it lasts ``min_duration_us``.

    Legs alternate direction over the same path with the same time map (leg
    k >= 1 starts where leg k-1 ended); at each turn the time map's slope is
    zero, so the camera stops smoothly within one sample interval and goes
    back (the slopes keep the Hermite map monotone inside every interval:
    Fritsch-Carlson's condition holds with one end slope zero, so s never
    leaves [0, L]). The last leg ends at the first sample at or after
    ``min_duration_us``. A trajectory already that long is returned as it is.
    The meta records ``legs`` (travelled duration over one leg's) and
    ``leg_duration_us``.

    Parameters
    ----------
    traj : a timed one-way path (t_us[0] == 0, s increasing).
    min_duration_us : shortest duration of the result, microseconds.
    """
    t, s, c2w, m = traj.t_us, traj.s, traj.c2w, traj.ds_dt
    D = int(t[-1] - t[0])
    if len(t) < 2 or D <= 0 or D >= min_duration_us:
        return traj
    n_legs = -(-int(min_duration_us) // D)
    if n_legs * len(t) > MAX_SAMPLES:
        raise ConfigError(f"trajectory.min_duration_s: {min_duration_us * 1e-6:g} s is {n_legs} legs of "
                         f"{D} us, {n_legs * len(t)} poses (at most {MAX_SAMPLES}); lower it or slow "
                         "the preset")
    parts_t, parts_s, parts_c, parts_m = [t], [s], [c2w], [m.copy()]
    for k in range(1, n_legs):
        fwd = k % 2 == 0
        tt = (t - t[0]) if fwd else (D - (t[::-1] - t[0]))
        parts_t.append(t[0] + k * D + tt[1:])
        parts_s.append((s if fwd else s[::-1])[1:])
        parts_c.append((c2w if fwd else c2w[::-1])[1:])
        parts_m.append((m if fwd else -m[::-1])[1:].copy())
        parts_m[-2][-1] = 0.0  # the turn
    t_all = np.concatenate(parts_t)
    end = int(np.searchsorted(t_all, t[0] + int(min_duration_us), side="left")) + 1
    t_all = t_all[:end]
    meta = dict(traj.meta, legs=float((t_all[-1] - t_all[0]) / D), leg_duration_us=D)
    return Trajectory(traj.curve, traj.arc, t_all, np.concatenate(parts_s)[:end],
                      np.concatenate(parts_m)[:end], np.concatenate(parts_c)[:end], traj.K,
                      traj.width, traj.height, meta)


def recorded_trajectory(t_us: np.ndarray, c2w: np.ndarray, K: np.ndarray, width: int, height: int,
                        meta: dict[str, Any]) -> Trajectory:
    """A trajectory through recorded timed poses (a real camera's ground truth).

    The pose curve is the interpolating cubic spline through the poses (linear
    for two), parameterised by their cumulative displacement (alpha 1 rad,
    beta 1 per scene unit); the time map passes through every (t_us_j, s_j),
    so ``pose_at(t_us_j)`` is the recorded pose j. Repeated poses (a camera at
    rest) are merged into the first of them: a path that stops and goes on is
    not representable by an arc-length map with a strictly increasing time.

    Parameters
    ----------
    t_us : (M,) int64 strictly increasing times, microseconds.
    c2w : (M, 4, 4) camera-to-world poses at those times (OpenCV axes).
    K, width, height : the camera the trajectory is rendered with.
    meta : recorded in the file (kind, source, time offset ...).
    """
    t_us = np.asarray(t_us, np.int64)
    if t_us.ndim != 1 or len(t_us) != len(c2w) or len(t_us) < 2 or np.any(np.diff(t_us) <= 0):
        raise InputError("a recorded path needs two or more poses at strictly increasing times")
    curve, arc, keep = fit_path_curve(check_c2w(c2w, "recorded poses"), 1.0, 1.0, "bspline")
    if len(keep) < 2:
        raise InputError("the recorded camera does not move: no path to follow")
    # the true arc length at each kept pose (its curve parameter is the knot), from the
    # dense arc table (interpolated: the poses at t_us_j match the recorded ones to the
    # table's resolution, 5e-5 m on slider_depth's 1 m path)
    s = np.interp(curve.breaks, arc.u, arc.L)
    path = SampledPath(curve, arc, s, c2w[keep].copy(), keep,
                       {"n_input": int(len(c2w)), "n_knots": int(len(keep)), "alpha": 1.0,
                        "beta_per_scene_unit": 1.0, "length_curve": arc.total})
    return timed_trajectory(path, t_us[keep], np.asarray(K, np.float64), int(width), int(height),
                            {"kind": "recorded", "method": "bspline", "preset": None, **meta})


def achieved_steps(c2w: np.ndarray, alpha: float, beta_n: float) -> np.ndarray:
    """Per-step displacement (M-1,) of sampled poses (chord of the metric)."""
    return pose_deltas(c2w, alpha, beta_n)


def achieved_steps_fine(path: SampledPath, alpha: float, beta_n: float,
                        max_evals: int = 2_000_000) -> np.ndarray:
    """Per-step arc length (M-1,) actually travelled between consecutive samples,
    measured by summing the metric over n sub-steps of each step (n <= 32, fewer
    for very long paths). Unlike the chord it is exact up to O(1/n^2) even where
    the path turns within a step."""
    M = len(path.s)
    n = int(max(2, min(32, max_evals // max(M - 1, 1))))
    if M < 2:
        return np.zeros(0)
    a, b = path.s[:-1], path.s[1:]
    ss = (a[:, None] + (b - a)[:, None] * np.linspace(0.0, 1.0, n + 1)[None]).ravel()
    P = eval_at_s(path.curve, path.arc, ss).reshape(M - 1, n + 1, 4, 4)
    ang = geodesic_angle(P[:, :-1, :3, :3], P[:, 1:, :3, :3]).sum(1)
    lin = np.linalg.norm(np.diff(P[:, :, :3, 3], axis=1), axis=2).sum(1)
    return alpha * ang + beta_n * lin


__all__ = ["Trajectory", "SampledPath", "build_base_path", "build_mini_paths", "points_in_view_fraction",
           "eval_at_s", "back_and_forth", "preset_duration_s", "image_steps_width", "timestamps_us",
           "timed_trajectory", "achieved_steps", "achieved_steps_fine", "hermite_eval"]
