"""Optical flow from depth and poses (gs2e.groundtruth.flow): closed forms,
the rendered plane scene, occlusion, DSEC's PNG encoding, hard cases."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.groundtruth.flow import (DSEC_MAX_PX, FlowSettings, decode_dsec_png, encode_dsec_png,
                                   fb_consistent, flow_between, flow_pair, motion_field,
                                   pixel_centres, sample_bilinear)
from gs2e.testing import look_at

W, H = 40, 30
K = np.array([[35.0, 0, 21.3], [0, 36.0, 14.7], [0, 0, 1]])


def _rot(axis, ang):
    from scipy.spatial.transform import Rotation

    return Rotation.from_rotvec(np.asarray(axis, float) / np.linalg.norm(axis) * ang).as_matrix()


def _plane_depth(c2w, n_w, d_w):
    """Depth map of the plane n . X = d (world) seen from c2w (camera z along each ray)."""
    u, v = pixel_centres(W, H)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    rays_w = rays_c @ c2w[:3, :3].T
    # C + z * ray hits the plane: n . (C + z r) = d
    return (d_w - n_w @ c2w[:3, 3]) / (rays_w @ n_w)


def _homography_flow(c2w_a, c2w_b, n_w, d_w):
    """Flow of the plane by its homography H = K_b (R - t n^T / d) K_a^-1 in camera a's frame."""
    R_ab = c2w_b[:3, :3].T @ c2w_a[:3, :3]
    t_ab = c2w_b[:3, :3].T @ (c2w_a[:3, 3] - c2w_b[:3, 3])
    n_a = c2w_a[:3, :3].T @ n_w
    d_a = d_w - n_w @ c2w_a[:3, 3]
    Hm = K @ (R_ab + np.outer(t_ab, n_a) / d_a) @ np.linalg.inv(K)
    u, v = pixel_centres(W, H)
    p = np.stack([u, v, np.ones_like(u)], -1) @ Hm.T
    return np.stack([p[..., 0] / p[..., 2] - u, p[..., 1] / p[..., 2] - v], -1)


def test_flow_of_a_tilted_plane_is_its_homography():
    n_w = np.array([0.2, -0.3, 1.0])
    n_w /= np.linalg.norm(n_w)
    d_w = 4.0
    a = look_at(np.array([0.3, -0.2, -2.0]), target=(0.1, 0.2, 4.0), up=(0, -1, 0))
    b = a.copy()
    b[:3, :3] = _rot([0.3, 1.0, -0.2], 0.05) @ a[:3, :3]
    b[:3, 3] += [0.15, -0.05, 0.2]
    za = _plane_depth(a, n_w, d_w)
    assert np.all(za > 0)
    flow, zb = flow_between(za, K, a, b)
    ref = _homography_flow(a, b, n_w, d_w)
    assert np.abs(flow - ref).max() < 1e-9
    assert np.abs(zb - _plane_depth_at(b, a, za)).max() < 1e-9


def _plane_depth_at(b, a, za):
    """Depth in camera b of the points of view a (direct transform)."""
    from gs2e.groundtruth.flow import backproject

    X = backproject(za, K) @ a[:3, :3].T + a[:3, 3]
    return ((X - b[:3, 3]) @ b[:3, :3])[..., 2]


def test_motion_field_is_the_derivative_of_the_displacement():
    n_w, d_w = np.array([0.0, 0.1, 1.0]) / np.linalg.norm([0, 0.1, 1]), 3.0
    a = np.eye(4)
    v_c, w_c = np.array([0.4, -0.2, 0.3]), np.array([0.2, -0.5, 0.1])
    z = _plane_depth(a, n_w, d_w)
    inst = motion_field(z, K, v_c, w_c)
    h = 1e-6
    b = np.eye(4)
    b[:3, :3] = _rot(w_c, np.linalg.norm(w_c) * h)
    b[:3, 3] = v_c * h
    disp, _ = flow_between(z, K, a, b)
    assert np.abs(disp / h - inst).max() < 1e-4 * np.abs(inst).max()


def test_rendered_plane_flow_matches_the_closed_form(tmp_path):
    """The analytic plane scene: a fronto-parallel plane of Gaussians at depth
    PLANE_DEPTH under a camera translating along x: flow = -f dx / Z exactly."""
    from gs2e.render.renderer import TrajectoryRenderer
    from gs2e.testing import PLANE_DEPTH, PLANE_F, plane_model, straight_trajectory

    r = TrajectoryRenderer(plane_model(tmp_path), straight_trajectory(tmp_path, dx=0.6))
    t0, t1 = r.t0_us + 0.3 * (r.t1_us - r.t0_us), r.t0_us + 0.5 * (r.t1_us - r.t0_us)
    a, b = r.pose(t0), r.pose(t1)
    _, alpha_a, depth_a = r.render_pose(a)
    _, alpha_b, depth_b = r.render_pose(b)
    fp = flow_pair(depth_a, alpha_a, depth_b, alpha_b, r.K, a, b)
    expect = -PLANE_F * (b[0, 3] - a[0, 3]) / PLANE_DEPTH
    m = fp.forward_valid
    assert m.mean() > 0.5  # all but the strip that leaves the view
    assert np.abs(fp.forward[m][:, 0] - expect).max() < 1e-3
    assert np.abs(fp.forward[m][:, 1]).max() < 1e-3
    # pixels whose point leaves the image are invalid
    u, _ = pixel_centres(r.width, r.height)
    leaves = (u + expect < 0) | (u + expect > r.width)
    assert not (m & leaves).any()


def test_occluded_and_disoccluded_pixels_are_invalid():
    """A box at depth 2 before a wall at depth 6; the camera moves right: the
    wall's pixels the box covers in view b (occlusion) and those it uncovers
    (disocclusion, seen from b) fail the forward-backward test."""
    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 0.4  # box flow -7 px, wall -2.3 px
    u, v = pixel_centres(W, H)

    def depth(c2w):
        # box |X| <= 0.4 at z = 2 in world; wall z = 6
        x_box = (u - K[0, 2]) / K[0, 0] * 2.0 + c2w[0, 3]
        y_box = (v - K[1, 2]) / K[1, 1] * 2.0
        return np.where((np.abs(x_box) <= 0.4) & (np.abs(y_box) <= 0.4), 2.0, 6.0)

    da, db = depth(a), depth(b)
    ones = np.ones((H, W))
    fp = flow_pair(da, ones, db, ones, K, a, b)
    fw = fp.forward
    box_a = da == 2.0
    assert np.abs(fw[box_a][:, 0] - (-K[0, 0] * 0.4 / 2.0)).max() < 1e-9
    # wall pixels of a whose point lands on the box in b: hidden there
    tx = np.clip(np.rint(u + fw[..., 0] - 0.5).astype(int), 0, W - 1)
    ty = np.clip(np.rint(v + fw[..., 1] - 0.5).astype(int), 0, H - 1)
    hidden = (~box_a) & (db[ty, tx] == 2.0) & (u + fw[..., 0] > 1) & (u + fw[..., 0] < W - 1)
    assert hidden.sum() > 10
    assert not fp.forward_valid[hidden].any()
    # away from the box and the image border every pixel is valid
    far = (np.abs(u - (K[0, 2] - 9)) > 14) & (u > 6) & (u < W - 6) & (np.abs(v - K[1, 2]) > 9) & ~box_a
    assert fp.forward_valid[far].all()
    assert fp.forward_valid[box_a & (u > 12)].all()


def test_alpha_and_unknown_depth_give_no_valid_flow():
    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 0.05
    z = np.full((H, W), 3.0)
    alpha = np.ones((H, W))
    alpha[:, :10] = 0.3  # partly covered: its expected depth is not a surface's
    z[5, 20] = np.nan
    z[6, 20] = 0.0
    z[7, 20] = np.inf
    fp = flow_pair(z, alpha, z, alpha, K, a, b, FlowSettings(alpha_min=0.5))
    assert not fp.forward_valid[:, :10].any()
    assert not fp.forward_valid[5:8, 20].any()
    assert fp.forward_valid[:, 15:30][np.isfinite(z[:, 15:30]) & (z[:, 15:30] > 0)].mean() > 0.9
    # all transparent: nothing valid, no crash
    none = flow_pair(z, 0 * alpha, z, 0 * alpha, K, a, b)
    assert not none.forward_valid.any() and np.isnan(none.forward).all()


def test_points_behind_the_other_camera_have_no_flow():
    a, b = np.eye(4), np.eye(4)
    b[2, 3] = 5.0  # camera b moved past the plane at z = 3
    flow, zb = flow_between(np.full((H, W), 3.0), K, a, b)
    assert np.isnan(flow).all() and np.isnan(zb).all()


def test_one_pixel_image():
    Kp = np.array([[10.0, 0, 0.5], [0, 10.0, 0.5], [0, 0, 1]])
    a, b = np.eye(4), np.eye(4)
    b[0, 3] = 0.01
    flow, _ = flow_between(np.full((1, 1), 2.0), Kp, a, b)
    assert flow[0, 0, 0] == pytest.approx(-10 * 0.01 / 2.0)
    # the target stays on the pixel; the same flow back is inconsistent, its negative is not
    assert not fb_consistent(flow, flow, abs_px2=1e-4)[0, 0]
    assert fb_consistent(flow, -flow)[0, 0]


def test_bilinear_sampling_of_affine_fields():
    u, v = pixel_centres(W, H)
    img = np.stack([2 * u - 3 * v + 1, 0.5 * u], -1)
    nan_img = img.copy()
    nan_img[3, 3] = np.nan
    assert np.isnan(sample_bilinear(nan_img, np.array([3.2]), np.array([3.7]))).all()
    assert np.isfinite(sample_bilinear(nan_img, np.array([10.2]), np.array([10.7]))).all()
    x = np.array([0.5, 3.25, W - 0.5, 0.4, 10.0, -0.01, 3.0])
    y = np.array([0.5, 7.75, H - 0.5, 2.0, H - 0.2, 1.0, H + 0.01])
    s = sample_bilinear(img, x, y)
    exact = np.array([True, True, True, False, False, False, False])
    # exact up to the position's rounding to 1/32 px (gradient (2, -3): 3.6 per px)
    tol = np.hypot(2, 3) / 32
    assert np.allclose(s[exact], np.stack([2 * x - 3 * y + 1, 0.5 * x], -1)[exact], atol=tol)
    # the outer half pixel takes the edge's value; beyond the image: NaN
    edge = np.stack([2 * 0.5 - 3 * 2.0 + 1, 0.25]), np.stack([2 * 10.0 - 3 * (H - 0.5) + 1, 5.0])
    assert np.allclose(s[3], edge[0], atol=tol) and np.allclose(s[4], edge[1], atol=tol)
    assert np.isnan(s[5:]).all()


def test_dsec_png_round_trip_and_channel_order(tmp_path):
    import cv2

    from gs2e.io.images import write_png

    rng = np.random.default_rng(0)
    flow = rng.uniform(-300, 300, (H, W, 2))
    valid = rng.random((H, W)) > 0.3
    flow[0, 0] = np.nan
    img = encode_dsec_png(flow, valid)
    path = tmp_path / "000000.png"
    write_png(path, img)
    back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert back.dtype == np.uint16
    rgb = back[..., ::-1]  # OpenCV reads BGR; DSEC's R = x
    f2, v2 = decode_dsec_png(rgb)
    fits = valid & np.all(np.abs(flow) <= DSEC_MAX_PX, axis=-1) & np.all(np.isfinite(flow), axis=-1)
    assert np.array_equal(v2, fits)
    assert np.abs(f2[fits] - flow[fits]).max() <= 0.5 / 128 + 1e-12
    assert np.all(f2[~fits] == 0)  # DSEC's invalid pixels hold zero flow
    # DSEC's own decoding of one pixel: (R - 2^15) / 128
    i, j = np.argwhere(fits)[0]
    assert (int(rgb[i, j, 0]) - 2 ** 15) / 128 == pytest.approx(flow[i, j, 0], abs=0.5 / 128)


def test_depth_at_a_time_between_frames_by_reprojection():
    """A tilted plane: the depth at an intermediate pose found from either
    frame equals the plane's own (per-pixel poses too); where the nearer frame
    does not show the point (off its image), the other one gives it."""
    from gs2e.groundtruth.flow import depth_at_time, depth_by_reprojection

    n_w = np.array([0.2, -0.3, 1.0]) / np.linalg.norm([0.2, -0.3, 1.0])
    d_w = 4.0
    a = look_at(np.array([0.3, -0.2, -2.0]), target=(0.1, 0.2, 4.0), up=(0, -1, 0))
    b = a.copy()
    b[:3, :3] = _rot([0.3, 1.0, -0.2], 0.08) @ a[:3, :3]
    b[:3, 3] += [0.4, -0.1, 0.2]
    t = a.copy()
    t[:3, :3] = _rot([0.3, 1.0, -0.2], 0.03) @ a[:3, :3]
    t[:3, 3] += [0.15, -0.04, 0.07]
    za, zb, zt = _plane_depth(a, n_w, d_w), _plane_depth(b, n_w, d_w), _plane_depth(t, n_w, d_w)
    u, v = pixel_centres(W, H)
    got = depth_by_reprojection(u, v, K, t, a, za, za)
    inside = np.isfinite(got)
    # exact up to the sampler's 1/32 px positions (and float32 inverse depth)
    assert inside.mean() > 0.8 and np.abs(got[inside] / zt[inside] - 1).max() < 2e-4
    both = depth_at_time(u, v, K, np.broadcast_to(t, (H, W, 4, 4)), np.full((H, W), 0.4), (a, za), (b, zb))
    assert np.isfinite(both).mean() >= inside.mean()
    ok = np.isfinite(both)
    assert np.abs(both[ok] / zt[ok] - 1).max() < 2e-4


def test_reprojection_refuses_what_the_frame_does_not_show():
    """The box before the wall: pixels of the camera at t that see wall the
    box hides in frame a get NaN from a (frame b, which shows it, answers)."""
    from gs2e.groundtruth.flow import depth_by_reprojection

    u, v = pixel_centres(W, H)

    def depth(x_cam):
        x_box = (u - K[0, 2]) / K[0, 0] * 2.0 + x_cam
        y_box = (v - K[1, 2]) / K[1, 1] * 2.0
        return np.where((np.abs(x_box) <= 0.4) & (np.abs(y_box) <= 0.4), 2.0, 6.0)

    a, t = np.eye(4), np.eye(4)
    t[0, 3] = 0.3
    za, zt = depth(0.0), depth(0.3)
    got = depth_by_reprojection(u, v, K, t, a, za, za)
    ok = np.isfinite(got)
    # exact away from the box's edge (bilinear samples there mix the two depths)
    import cv2

    edge = cv2.dilate((np.abs(np.diff(zt, axis=1, prepend=zt[:, :1])) > 0).astype(np.uint8)
                      | (np.abs(np.diff(zt, axis=0, prepend=zt[:1])) > 0).astype(np.uint8), np.ones((5, 5)))
    clean = ok & ~edge.astype(bool)
    assert clean.sum() > 0.5 * ok.size and np.abs(got[clean] - zt[clean]).max() < 1e-6
    assert (np.abs(got[ok] - zt[ok]) > 1e-3).sum() <= 2 * H  # a column of pixels at most
    # some of t's wall pixels hide behind the box in a: refused, not given the box's depth
    assert (~ok & (zt == 6.0)).sum() > 5
