"""Quaternion helpers added to gs2e.common.so3 for the trajectory stage."""

import numpy as np
import pytest

from gs2e.common.so3 import (geodesic_angle, quat_angle, quat_exp, quat_log,
                             quat_make_continuous, quat_mean, quat_multiply,
                             quat_to_rotmat, rotmat_to_quat)


def _rand_quats(n, seed=0):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def test_multiply_matches_matrix_product():
    a, b = _rand_quats(50, 1), _rand_quats(50, 2)
    np.testing.assert_allclose(quat_to_rotmat(quat_multiply(a, b)),
                               quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-12)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-7, 0.3, np.pi - 1e-6, np.pi - 1e-10, np.pi])
def test_log_exp_roundtrip_near_0_and_pi(angle):
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    r = axis * angle
    q = quat_exp(r)
    assert np.isclose(np.linalg.norm(q), 1.0, atol=1e-15)
    r2 = quat_log(q)
    assert np.isclose(np.linalg.norm(r2), angle, rtol=1e-9, atol=1e-15)
    # the same rotation from the antipodal quaternion
    np.testing.assert_allclose(quat_to_rotmat(quat_exp(quat_log(-q))), quat_to_rotmat(q), atol=1e-12)


def test_quat_angle_stable_and_sign_free():
    for ang in [1e-9, 1e-4, 1.0, np.pi - 1e-7]:
        qa = _rand_quats(1, 3)[0]
        qb = quat_multiply(qa, quat_exp(np.array([0.0, 0.0, ang])))
        assert np.isclose(quat_angle(qa, qb), ang, rtol=1e-7, atol=1e-15)
        assert np.isclose(quat_angle(qa, -qb), ang, rtol=1e-7, atol=1e-15)
        Ra, Rb = quat_to_rotmat(qa), quat_to_rotmat(qb)
        assert np.isclose(geodesic_angle(Ra, Rb), ang, rtol=1e-6, atol=1e-12)


def test_make_continuous_removes_sign_flips():
    # a slow rotation sampled as matrices -> quaternions with w >= 0 jump at 180 deg
    ang = np.linspace(0, 3 * np.pi, 40)
    q = quat_exp(np.stack([np.zeros_like(ang), np.zeros_like(ang), ang], 1))
    q_std = rotmat_to_quat(quat_to_rotmat(q))  # w >= 0: a sign jump
    assert np.any(np.einsum("ij,ij->i", q_std[1:], q_std[:-1]) < 0)
    qc = quat_make_continuous(q_std)
    assert np.all(np.einsum("ij,ij->i", qc[1:], qc[:-1]) >= 0)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", qc, q)), 1.0, atol=1e-12)


def test_quat_mean_sign_aligned():
    q0 = quat_exp(np.array([0.0, 0.0, 0.2]))
    q1 = quat_exp(np.array([0.0, 0.0, 0.4]))
    m = quat_mean(np.stack([q0, -q1]))  # a flipped sign must not matter
    assert np.isclose(quat_angle(m, quat_exp(np.array([0.0, 0.0, 0.3]))), 0.0, atol=1e-12)
    # two rotations 180 deg apart: the midpoint is the 90 deg rotation
    a, b = np.array([1.0, 0, 0, 0]), np.array([0.0, 1, 0, 0])
    m = quat_mean(np.stack([a, b]))
    assert np.isclose(quat_angle(m, quat_exp(np.array([np.pi / 2, 0, 0]))), 0.0, atol=1e-12)
