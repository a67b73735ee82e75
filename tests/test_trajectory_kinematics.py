"""Exact time derivatives of trajectories (gs2e.trajectory.kinematics): against
the poses themselves and central differences, where the path is not C^2 and
by how much, and the degenerate paths."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.testing import make_scene, ring
from gs2e.trajectory.kinematics import acceleration_jumps, kinematics_at, knot_times_us
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.stage import generate


@pytest.fixture(scope="module")
def trajectories():
    cfg = TrajectorySettings.defaults(plot=False, min_duration_s=1.5)
    return generate(make_scene(ring(20, noise=0.05)), cfg, seed=0).trajectories


def _central(tr, t, h_us):
    P, Pp, Pm = tr.pose_at(t), tr.pose_at(t + h_us), tr.pose_at(t - h_us)
    h = h_us * 1e-6
    v = (Pp[:, :3, 3] - Pm[:, :3, 3]) / (2 * h)
    a = (Pp[:, :3, 3] - 2 * P[:, :3, 3] + Pm[:, :3, 3]) / h ** 2
    dR = np.einsum("qji,qjk->qik", P[:, :3, :3], (Pp[:, :3, :3] - Pm[:, :3, :3]) / (2 * h))
    return v, a, np.stack([dR[:, 2, 1], dR[:, 0, 2], dR[:, 1, 0]], 1)


@pytest.mark.parametrize("name", ["base_mild", "base_strong", "mini01_medium"])
def test_derivatives_match_the_poses(trajectories, name):
    tr = trajectories[name]
    t = np.linspace(tr.t_us[0], tr.t_us[-1], 3001)[1:-1]
    k = kinematics_at(tr, t)
    assert np.abs(k.c2w - tr.pose_at(t)).max() < 1e-12
    knots = knot_times_us(tr)
    away = np.min(np.abs(t[:, None] - knots[None, :]), axis=1) > 10.0  # us: no piece joins within +-h
    v, a, w = _central(tr, t, 4.0)
    scale_v, scale_a, scale_w = (np.abs(x).max() for x in (v, a, w))
    assert np.abs(k.velocity_w - v).max() < 1e-6 * scale_v
    assert np.abs(k.omega_c - w).max() < 1e-6 * scale_w
    assert np.abs(k.accel_w - a)[away].max() < 2e-3 * scale_a
    # the angular acceleration, against differences of the exact angular velocity
    kp, km = kinematics_at(tr, t + 1.0), kinematics_at(tr, t - 1.0)
    al = (kp.omega_c - km.omega_c) / 2e-6
    assert np.abs(k.alpha_c - al)[away].max() < 1e-4 * np.abs(al).max()


def test_jumps_are_found_and_measured(trajectories):
    tr = trajectories["mini00_medium"]
    rep = acceleration_jumps(tr)
    assert rep["n_knots"] > len(tr.t_us) - 2  # the time map's samples and the arc table's nodes
    assert not rep["c2"] and rep["accel_jump_max_m_s2"] > 0
    assert rep["velocity_jump_max_m_s"] < 1e-9 * rep["accel_rms_m_s2"] + 1e-12  # C^1
    # the one-sided limits at the largest jump differ by what is reported
    t = np.array([rep["accel_jump_max_t_us"]])
    d = kinematics_at(tr, t, "right").accel_w - kinematics_at(tr, t, "left").accel_w
    assert np.linalg.norm(d) == pytest.approx(rep["accel_jump_max_m_s2"], rel=1e-12)
    # and the knots are real joins: just inside a piece the two sides agree
    k = knot_times_us(tr)
    mid = 0.5 * (k[:-1] + k[1:])
    same = kinematics_at(tr, mid, "right").accel_w - kinematics_at(tr, mid, "left").accel_w
    assert np.abs(same).max() < 1e-9 * rep["accel_rms_m_s2"]


def test_metres_per_unit_scales_the_report(trajectories):
    tr = trajectories["base_mild"]
    a, b = acceleration_jumps(tr), acceleration_jumps(tr, metres_per_unit=0.25)
    assert b["accel_rms_m_s2"] == pytest.approx(0.25 * a["accel_rms_m_s2"])
    assert b["alpha_rms_rad_s2"] == pytest.approx(a["alpha_rms_rad_s2"])


def test_straight_constant_speed(tmp_path):
    from gs2e.testing import straight_trajectory
    from gs2e.trajectory import load_trajectory

    tr = load_trajectory(straight_trajectory(tmp_path, dx=0.6))
    t = np.linspace(tr.t_us[0], tr.t_us[-1], 101)
    k = kinematics_at(tr, t)
    v = k.velocity_w[:, 0]
    # constant up to the integer-microsecond sample times and the arc table
    assert np.allclose(v, v[0], rtol=1e-4) and v[0] > 0
    assert np.abs(k.velocity_w[:, 1:]).max() < 1e-12
    assert np.abs(k.accel_w).max() * tr.duration_us * 1e-6 < 1e-3 * v[0]
    assert np.abs(k.omega_c).max() == 0.0


def test_outside_and_one_sample(trajectories):
    tr = trajectories["base_mild"]
    with pytest.raises(ValueError, match="must lie in"):
        kinematics_at(tr, np.array([tr.t_us[-1] + 1.0]))
    with pytest.raises(ValueError, match="finite"):
        kinematics_at(tr, np.array([np.nan]))
    from gs2e.trajectory.trajectory import Trajectory

    d = tr.to_arrays()
    one = Trajectory.from_arrays({**d, "t_us": d["t_us"][:1], "s": d["s"][:1], "ds_dt": d["ds_dt"][:1],
                                  "c2w": d["c2w"][:1]})
    k = kinematics_at(one, np.array([float(one.t_us[0])]))
    assert not np.any(k.velocity_w) and not np.any(k.accel_w) and not np.any(k.omega_c)
    assert acceleration_jumps(one)["n_knots"] == 0
