"""Base paths and timed trajectories: hard inputs and the stated properties."""

import math

import numpy as np
import pytest

from gs2e.testing import TEMPLE, fine_steps, look_at, ring, temple_c2w
from gs2e.common.errors import InputError
from gs2e.common.so3 import geodesic_angle, quat_exp, quat_to_rotmat, rotmat_to_quat
from gs2e.trajectory.curve import (arc_length_table, curve_speed, curve_speed_numpy, fit_curve,
                                   smooth_poses, split_c2w)
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.trajectory import build_base_path, timed_trajectory, timestamps_us
from gs2e.trajectory.velocity import parse_velocity_expression, speed_list_profile

V_DEFAULT = parse_velocity_expression("0.25*sin(t)+1.1")


def cfg(**kw) -> TrajectorySettings:
    return TrajectorySettings.defaults(**kw)


def timed(path, dur_s=2.0):
    return timed_trajectory(path, timestamps_us(dur_s, len(path.s)), np.eye(3), 8, 6, {})


def assert_profile(path, v_expected, tol=1e-3):
    tr = timed(path)
    got = fine_steps(tr, path.info["alpha"], path.info["beta_per_scene_unit"])
    want = v_expected[:-1] / v_expected[:-1].sum()
    rel = np.abs((got / got.sum()) / want - 1)
    assert rel.max() <= tol, f"max relative step error {rel.max():.2e}"
    return rel.max()


def assert_valid_poses(c2w):
    assert np.all(np.isfinite(c2w))
    R = c2w[:, :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-10)
    assert np.all(np.linalg.det(R) > 0)
    np.testing.assert_array_equal(c2w[:, 3], np.broadcast_to([0, 0, 0, 1.0], (len(c2w), 4)))


# ---------------------------------------------------------------- properties

@pytest.mark.parametrize("method", ["bspline", "bezier", "linear"])
def test_speed_profile_matches_and_endpoints_preserved(method):
    c2w = ring(24, noise=0.02)
    p = build_base_path(c2w, cfg(interpolation=method, gamma=10), V_DEFAULT)
    assert len(p.c2w) == 240
    assert_valid_poses(p.c2w)
    assert_profile(p, V_DEFAULT(np.linspace(0, 1, 240)))
    sm = smooth_poses(c2w, 2)
    np.testing.assert_allclose(p.c2w[0], sm[0], atol=1e-12)
    np.testing.assert_allclose(p.c2w[-1], sm[-1], atol=1e-12)


def test_velocity_expression_ratio_1_to_1000():
    v = parse_velocity_expression("1 + 999*t**3")
    p = build_base_path(ring(15, noise=0.01), cfg(gamma=60, velocity="1 + 999*t**3"), v)
    assert_profile(p, v(np.linspace(0, 1, len(p.c2w))))


def test_velocity_ratio_1_to_1000():
    c2w = ring(20, noise=0.01)
    v = speed_list_profile([1.0, 1000.0, 1.0], 0.1)
    p = build_base_path(c2w, cfg(gamma=100, speed_list=[1.0, 1000.0, 1.0]), v)
    M = len(p.c2w)
    vt = v(np.linspace(0, 1, M))
    assert vt.max() / vt.min() > 999
    assert_profile(p, vt)


def test_real_temple_ring_profile():
    if not TEMPLE.exists():
        pytest.skip(f"real data not found: {TEMPLE}")
    c2w = temple_c2w(30)
    p = build_base_path(c2w, cfg(gamma=8), V_DEFAULT)
    assert_valid_poses(p.c2w)
    assert_profile(p, V_DEFAULT(np.linspace(0, 1, len(p.c2w))))


def _one_sided_derivs(tr, t0, eps):
    P = tr.pose_at(np.array([t0 - 2 * eps, t0 - eps, t0, t0 + eps, t0 + 2 * eps]))
    X = np.concatenate([P[:, :3, 3], P[:, :3, :3].reshape(5, 9)], axis=1)
    left = (3 * X[2] - 4 * X[1] + X[0]) / (2 * eps)   # second-order one-sided
    right = (-3 * X[2] + 4 * X[3] - X[4]) / (2 * eps)
    return left, right


def _knot_times(tr):
    """Times at which the path crosses the curve knots (away from the ends)."""
    s_knots = np.interp(tr.curve.breaks[1:-1], tr.arc.u, tr.arc.L)
    return np.interp(s_knots, tr.s, tr.t_us.astype(float))


@pytest.mark.parametrize("method,c1", [("bspline", True), ("bezier", True), ("linear", False)])
def test_c1_continuity_in_time(method, c1):
    p = build_base_path(ring(12, noise=0.05), cfg(interpolation=method, gamma=5), V_DEFAULT)
    tr = timed(p, dur_s=10.0)
    times = np.concatenate([_knot_times(tr), tr.t_us[5:-5:7].astype(float)])
    eps = 20.0  # us, on a 10 s path
    jumps = []
    for t0 in times:
        l, r = _one_sided_derivs(tr, t0, eps)
        jumps.append(np.abs(l - r).max() / (np.abs(l).max() + np.abs(r).max()))
    jumps = np.array(jumps)
    if c1:
        assert jumps.max() < 1e-3, jumps.max()
    else:  # the check can fail: linear interpolation has velocity jumps at knots
        assert jumps.max() > 1e-2


def test_pose_at_reproduces_samples_and_is_vectorised():
    p = build_base_path(ring(10, noise=0.02), cfg(), V_DEFAULT)
    tr = timed(p)
    np.testing.assert_array_equal(tr.pose_at(tr.t_us), p.c2w)
    # unsorted queries give the same poses as sorted ones
    rng = np.random.default_rng(0)
    q = rng.uniform(0, tr.t_us[-1], 500)
    np.testing.assert_array_equal(tr.pose_at(q), tr.pose_at(np.sort(q))[np.argsort(np.argsort(q))])
    with pytest.raises(ValueError, match="times must lie"):
        tr.pose_at(np.array([-1.0]))
    with pytest.raises(ValueError, match="finite"):
        tr.pose_at(np.array([np.nan]))


def test_curve_speed_kernel_matches_numpy():
    T, q = split_c2w(ring(9, noise=0.05))
    u = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(T, axis=0), axis=1))])
    c = fit_curve(u, T, q, "bspline")
    x = np.linspace(0, u[-1], 777)
    np.testing.assert_allclose(curve_speed(c, x, 0.7, 1.3), curve_speed_numpy(c, x, 0.7, 1.3), rtol=1e-10)


# ---------------------------------------------------------------- hard inputs

def test_duplicate_consecutive_poses():
    base = ring(10, noise=0.02)
    c2w = np.concatenate([base[:1], base[:1], base[:1], base[1:4], base[3:4], base[3:4], base[4:], base[-1:]])
    for w in (0, 2):
        p = build_base_path(c2w, cfg(smooth_half_width=w), V_DEFAULT)
        assert_valid_poses(p.c2w)
        if w == 0:  # exact duplicates become zero-length segments and are merged
            assert p.info["n_knots"] == len(c2w) - 5
        assert np.all(np.diff(p.s) > 0)
        assert_profile(p, V_DEFAULT(np.linspace(0, 1, len(p.c2w))))


def test_all_poses_identical_and_single_pose():
    one = ring(3)[1:2]
    for c2w in (one, np.repeat(one, 6, axis=0)):
        p = build_base_path(c2w, cfg(gamma=5), V_DEFAULT)
        assert len(p.c2w) == max(2, math.ceil(5 * len(c2w)))
        np.testing.assert_allclose(p.c2w, np.broadcast_to(one[0], p.c2w.shape), atol=1e-12)
        assert p.info["length_curve"] == 0.0 and np.all(p.s == 0.0)
        tr = timed(p)
        assert np.all(np.diff(tr.t_us) > 0)
        np.testing.assert_allclose(tr.pose_at(np.array([0.0, tr.t_us[-1] / 3])), np.stack([one[0]] * 2), atol=1e-12)


def _yaw_poses(yaws_deg, step=0.3):
    out = []
    for i, y in enumerate(np.radians(yaws_deg)):
        T = np.eye(4)
        T[:3, :3] = quat_to_rotmat(quat_exp(np.array([0.0, y, 0.0])))  # yaw about camera y
        T[:3, 3] = [step * i, 0.0, 0.0]
        out.append(T)
    return np.stack(out)


def test_180_degree_rotation_between_neighbours():
    c2w = _yaw_poses([0, 20, 200, 220, 240, 420])  # two exact 180 deg steps
    p = build_base_path(c2w, cfg(smooth_half_width=0, gamma=20), V_DEFAULT)
    assert_valid_poses(p.c2w)
    steps = geodesic_angle(p.c2w[:-1, :3, :3], p.c2w[1:, :3, :3])
    key = geodesic_angle(c2w[:-1, :3, :3], c2w[1:, :3, :3]).sum()
    # no detour through the antipode: total rotation close to the keyframes' sum
    assert steps.max() < np.radians(30)
    assert steps.sum() < 1.15 * key
    assert_profile(p, V_DEFAULT(np.linspace(0, 1, len(p.c2w))))
    # also through smoothing
    p2 = build_base_path(c2w, cfg(smooth_half_width=2), V_DEFAULT)
    assert_valid_poses(p2.c2w)


def test_quaternion_sign_flips_do_not_change_the_curve():
    T, q = split_c2w(ring(8, noise=0.05))
    u = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(T, axis=0), axis=1))])
    flips = np.array([1, -1, -1, 1, -1, 1, 1, -1.0])[:, None]
    c1, c2 = fit_curve(u, T, q, "bspline"), fit_curve(u, T, q * flips, "bspline")
    x = np.linspace(0, u[-1], 301)
    np.testing.assert_allclose(c1.c2w(x), c2.c2w(x), atol=1e-12)
    # the arc-length of a rotation-only path equals the keyframes' geodesic sum (no detours)
    R = quat_to_rotmat(quat_exp(np.outer(np.linspace(0, 3.0, 8), [0.0, 0.0, 1.0])))
    qq = rotmat_to_quat(R) * flips  # w >= 0 standard form, then random flips
    c = fit_curve(np.linspace(0, 3.0, 8), np.zeros((8, 3)), qq, "bspline")
    assert np.isclose(arc_length_table(c, 1.0, 0.0).total, 3.0, rtol=1e-9)


@pytest.mark.parametrize("N", [2, 3])
def test_fewer_than_four_poses(N):
    c2w = ring(N, arc=1.0)
    p = build_base_path(c2w, cfg(smooth_half_width=0, gamma=40), V_DEFAULT)
    assert_valid_poses(p.c2w)
    np.testing.assert_allclose(p.c2w[[0, -1]], c2w[[0, -1]], atol=1e-12)
    assert_profile(p, V_DEFAULT(np.linspace(0, 1, len(p.c2w))))


def test_collinear_centres_stay_on_the_line():
    d = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    c2w = np.stack([look_at(d * x + np.array([0, 0, 5.0]), target=(0, 0, -100), up=(0, 1, 0)) for x in
                    [0, 0.1, 0.5, 0.6, 2.0, 2.1, 3.0]])
    p = build_base_path(c2w, cfg(smooth_half_width=1, gamma=20), V_DEFAULT)
    C = p.c2w[:, :3, 3] - np.array([0, 0, 5.0])
    off = C - np.outer(C @ d, d)
    assert np.abs(off).max() < 1e-9
    assert_profile(p, V_DEFAULT(np.linspace(0, 1, len(p.c2w))))


def test_nan_pose_is_a_clear_error():
    c2w = ring(6)
    c2w[3, 1, 2] = np.nan
    with pytest.raises(InputError, match="pose 3 contains NaN"):
        build_base_path(c2w, cfg(), V_DEFAULT)
    bad = ring(4)
    bad[2, :3, :3] *= 2.0
    with pytest.raises(InputError, match="pose 2 is not a proper rotation"):
        build_base_path(bad, cfg(), V_DEFAULT)
    with pytest.raises(InputError, match="shape"):
        build_base_path(np.zeros((3, 3, 4)), cfg(), V_DEFAULT)
