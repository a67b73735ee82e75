"""Optical flow of a static scene from depth and camera motion.

Conventions: pixel (column j, row i) has its centre at (j + 0.5, i + 0.5)
(the renderer's); flow is (dx, dy) in pixels, +x right, +y down; depth is
camera z (scene units) along the optical axis; poses are camera-to-world,
OpenCV axes.

- **Displacement flow** between two views (:func:`flow_between`): each pixel's
  surface point (back-projected with its depth) projected into the other view.
  Exact wherever the depth is, for any motion.
- **Instantaneous flow** (:func:`motion_field`, px/s): the motion field of a
  static point seen by a camera moving with velocity v and angular velocity
  omega (both in the camera frame): dX/dt = -v - omega x X for the point's
  camera coordinates X (Longuet-Higgins and Prazdny, Proc. R. Soc. B 208,
  1980), then the derivative of the pinhole projection.
- **Validity** (:func:`flow_pair`): the pixel is opaque (alpha >= alpha_min,
  so its expected depth is a surface's), its point lies in front of the other
  camera and inside its image, and the forward and backward flows agree
  (Sundaram, Brox and Keutzer, ECCV 2010: |w_f + w_b|^2 <= rel (|w_f|^2 +
  |w_b|^2) + abs): a point hidden in the other view (occlusion) or a pixel
  that only the other view sees (disocclusion) fails that test, because the
  backward flow there belongs to another surface.
- **DSEC's 16-bit PNG** (:func:`encode_dsec_png`): R = dx * 128 + 2^15, G =
  dy * 128 + 2^15, B = valid (0/1); flow 0 where invalid (DSEC's
  ``check_optical_flow_submission.py`` and E-RAFT's ``flow_16bit_to_float``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

DSEC_SCALE = 128.0     # PNG steps per pixel of flow
DSEC_OFFSET = 2 ** 15  # PNG value of zero flow
DSEC_MAX_PX = (2 ** 16 - 1 - DSEC_OFFSET) / DSEC_SCALE  # largest representable |dx|, |dy|
# A pixel is a surface's where the model covers it at least this much: what
# "covered" (alpha > 0.5) means elsewhere in gs2e.
ALPHA_MIN = 0.5
# The forward-backward test's tolerances (Sundaram, Brox and Keutzer, ECCV 2010).
FB_REL, FB_ABS_PX2 = 0.01, 0.5


def pixel_centres(width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, v), each (H, W) float64: pixel centres, x = column + 0.5, y = row + 0.5."""
    return np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)


def backproject(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera coordinates (H, W, 3) of every pixel centre at its depth (H, W)."""
    H, W = depth.shape
    u, v = pixel_centres(W, H)
    z = np.asarray(depth, np.float64)
    return np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)


def flow_between(depth_a: np.ndarray, K_a: np.ndarray, c2w_a: np.ndarray, c2w_b: np.ndarray,
                 K_b: np.ndarray | None = None, near: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Displacement of every pixel of view a to where its surface point lands
    in view b.

    Parameters
    ----------
    depth_a : (H, W) camera z of view a (scene units); NaN, inf or <= 0 where
        unknown.
    K_a, K_b : (3, 3) intrinsics (K_b defaults to K_a); c2w_a, c2w_b : (4, 4).
    near : points at z <= near in view b get no flow.

    Returns
    -------
    flow (H, W, 2) float64 px (NaN where the depth is unknown or the point is
    behind camera b), and the point's depth in view b (H, W).
    """
    K_b = K_a if K_b is None else K_b
    X = backproject(depth_a, K_a)
    R_a, R_b = c2w_a[:3, :3], c2w_b[:3, :3]
    # X_b = R_b^T (R_a X + C_a - C_b), in one matrix for all pixels
    Xb = X @ (R_b.T @ R_a).T + R_b.T @ (c2w_a[:3, 3] - c2w_b[:3, 3])
    z_b = Xb[..., 2]
    ok = np.isfinite(depth_a) & (depth_a > 0) & (z_b > near)
    with np.errstate(divide="ignore", invalid="ignore"):
        xb = K_b[0, 0] * Xb[..., 0] / z_b + K_b[0, 2]
        yb = K_b[1, 1] * Xb[..., 1] / z_b + K_b[1, 2]
    H, W = depth_a.shape
    u, v = pixel_centres(W, H)
    flow = np.stack([xb - u, yb - v], axis=-1)
    flow[~ok] = np.nan
    return flow, np.where(ok, z_b, np.nan)


def motion_field_at(u: np.ndarray, v: np.ndarray, z: np.ndarray, K: np.ndarray,
                    velocity_c: np.ndarray, omega_c: np.ndarray) -> np.ndarray:
    """Instantaneous image velocity (..., 2) px/s of static points seen at
    pixels (u, v) (pixel coordinates, centres at +0.5) with depth z (camera
    z, scene units), by a camera moving with velocity_c (scene units/s) and
    omega_c (rad/s), both in the camera frame and broadcast against u
    ((3,) or (..., 3)). NaN where z is not a positive finite depth."""
    z = np.asarray(z, np.float64)
    x = (np.asarray(u, np.float64) - K[0, 2]) / K[0, 0] * z
    y = (np.asarray(v, np.float64) - K[1, 2]) / K[1, 1] * z
    X = np.stack([x, y, z], axis=-1)
    Xd = -np.asarray(velocity_c, np.float64) - np.cross(np.asarray(omega_c, np.float64), X)
    with np.errstate(divide="ignore", invalid="ignore"):
        du = K[0, 0] * (Xd[..., 0] * z - x * Xd[..., 2]) / (z * z)
        dv = K[1, 1] * (Xd[..., 1] * z - y * Xd[..., 2]) / (z * z)
    out = np.stack([du, dv], axis=-1)
    out[~(np.isfinite(z) & (z > 0))] = np.nan
    return out


def motion_field(depth: np.ndarray, K: np.ndarray, velocity_c: np.ndarray,
                 omega_c: np.ndarray) -> np.ndarray:
    """Instantaneous optical flow (H, W, 2) px/s of a depth map (H, W) under
    the camera's velocity and angular velocity (camera frame; see
    :func:`motion_field_at`)."""
    H, W = depth.shape
    u, v = pixel_centres(W, H)
    return motion_field_at(u, v, depth, K, velocity_c, omega_c)


def sample_bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``img`` (H, W, C) at pixel coordinates (x, y) (any shape; centres at
    +0.5), bilinear between the four nearest centres (the outer half pixel
    takes the edge's values); NaN outside the image [0, W] x [0, H] or where a
    neighbour is NaN. float32, by OpenCV's remap, whose bilinear weights are
    those of the position rounded to 1/32 px (its INTER_BITS = 5)."""
    import cv2

    img = np.asarray(img, np.float32)
    H, W, C = img.shape
    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    inside = (x >= 0) & (x <= W) & (y >= 0) & (y <= H)
    n = x.size
    cols = max(1, min(n, 1024))  # remap's maps: fewer than 2^15 rows and columns
    rows = -(-n // cols)

    def as_map(a):
        m = np.zeros(rows * cols, np.float32)
        m[:n] = a.reshape(-1) - 0.5
        return m.reshape(rows, cols)

    mx, my = as_map(x), as_map(y)
    out = np.empty((rows * cols, C), np.float32)
    for c0 in range(0, C, 4):  # remap takes up to 4 channels
        c1 = min(C, c0 + 4)
        r = cv2.remap(np.ascontiguousarray(img[..., c0:c1]), mx, my, cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
        out[:, c0:c1] = r.reshape(-1, c1 - c0)
    out = out[:n].reshape(x.shape + (C,))
    out[~inside] = np.nan
    return out


def fb_consistent(flow_fw: np.ndarray, flow_bw: np.ndarray, rel: float = FB_REL,
                  abs_px2: float = FB_ABS_PX2) -> np.ndarray:
    """(H, W) bool: the forward flow's target lies in view b's image and the
    backward flow sampled there brings the pixel back:
    |w_f + w_b|^2 <= rel (|w_f|^2 + |w_b|^2) + abs_px2 (Sundaram et al. 2010;
    their rel 0.01 and abs 0.5 px^2 are the defaults)."""
    H, W = flow_fw.shape[:2]
    u, v = pixel_centres(W, H)
    wb = sample_bilinear(flow_bw, u + flow_fw[..., 0], v + flow_fw[..., 1])
    with np.errstate(invalid="ignore"):
        err = np.sum((flow_fw + wb) ** 2, axis=-1)
        bound = rel * (np.sum(flow_fw ** 2, axis=-1) + np.sum(wb ** 2, axis=-1)) + abs_px2
        return np.isfinite(err) & (err <= bound)


@dataclass(frozen=True)
class FlowSettings:
    """How flow is judged valid: the export and the benchmark's flow task
    share these (module constants, one declaration).

    alpha_min : a pixel's coverage (alpha) at least this for its expected
        depth to count as a surface's.
    fb_rel, fb_abs_px2 : the forward-backward test's relative and absolute
        (px^2) tolerances.
    """

    alpha_min: float = ALPHA_MIN
    fb_rel: float = FB_REL
    fb_abs_px2: float = FB_ABS_PX2


@dataclass(frozen=True)
class FlowPair:
    """Flow between two frames a -> b and back: forward (H, W, 2) px, backward
    (H, W, 2) px (from b to a, on b's pixels), and their validity (H, W) bool.
    Invalid pixels hold NaN only where no flow exists (unknown depth, behind
    the camera); occluded ones keep their geometric flow."""

    forward: np.ndarray
    backward: np.ndarray
    forward_valid: np.ndarray
    backward_valid: np.ndarray


def surface_depth(depth: np.ndarray, alpha: np.ndarray, alpha_min: float) -> np.ndarray:
    """Depth (H, W) float64 where the pixel is opaque enough, NaN elsewhere."""
    d = np.asarray(depth, np.float64)
    return np.where((np.asarray(alpha) >= alpha_min) & np.isfinite(d) & (d > 0), d, np.nan)


def flow_pair(depth_a: np.ndarray, alpha_a: np.ndarray, depth_b: np.ndarray, alpha_b: np.ndarray,
              K: np.ndarray, c2w_a: np.ndarray, c2w_b: np.ndarray,
              settings: FlowSettings = FlowSettings()) -> FlowPair:
    """Forward and backward flow of two rendered frames of one camera and
    their validity (module docstring).

    depth_* : (H, W) expected camera z; alpha_* : (H, W) coverage in [0, 1];
    K : (3, 3); c2w_* : (4, 4).
    """
    za = surface_depth(depth_a, alpha_a, settings.alpha_min)
    zb = surface_depth(depth_b, alpha_b, settings.alpha_min)
    fw, _ = flow_between(za, K, c2w_a, c2w_b)
    bw, _ = flow_between(zb, K, c2w_b, c2w_a)
    ok_f = fb_consistent(fw, bw, settings.fb_rel, settings.fb_abs_px2)
    ok_b = fb_consistent(bw, fw, settings.fb_rel, settings.fb_abs_px2)
    return FlowPair(fw, bw, ok_f, ok_b)


def depth_by_reprojection(u: np.ndarray, v: np.ndarray, K: np.ndarray, c2w_t: np.ndarray,
                          c2w_f: np.ndarray, depth_f: np.ndarray, z0: np.ndarray,
                          iters: int = 6, tol: float = 0.01) -> np.ndarray:
    """The depth at pixels (u, v) (coordinates (...), centres at +0.5) of the
    camera at some time t, from a rendered frame f's surface depth (H, W)
    (NaN where none) and both exact poses, for a static scene: c2w_t (4, 4),
    or (..., 4, 4) one pose per pixel (events at their own times).

    A fixed point on z from the guess ``z0``: the point at depth z along the
    pixel's ray projects into frame f at p_f; the surface there (bilinear in
    inverse depth, exact across a plane, at positions rounded to 1/32 px by
    :func:`sample_bilinear`) is the point X'; z becomes X''s depth in camera t. Where after
    ``iters`` steps X' and the ray's point disagree by more than ``tol`` of
    their depth in f, the pixel sees at t what f does not show there (an
    occlusion, or the guess converged nowhere): NaN. On the demo at 8 times
    between frames against the depth rendered there (benchmarks/
    bench_groundtruth.py), it puts the motion field within 0.3 / 0.8 / 1.6 %
    (median) of the rendered depth's at mild / medium / strong, and keeps 99 /
    98 / 91 % of the pixels, where depth linear in time between the two frames
    at the same pixel had 0.8 / 2.4 / 4.9 % and kept 84 / 64 / 38 %. Sampled
    positions beyond frame f's outer pixel centres are not extrapolated (NaN).
    """
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    z = np.asarray(z0, np.float64).copy()
    ray = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    c2w_t = np.asarray(c2w_t, np.float64)
    Rf = np.asarray(c2w_f, np.float64)[:3, :3]
    R_ft = np.einsum("ji,...jk->...ik", Rf, c2w_t[..., :3, :3])        # camera t -> camera f
    t_ft = (c2w_t[..., :3, 3] - c2w_f[:3, 3]) @ Rf
    R_tf = np.swapaxes(R_ft, -1, -2)                                   # camera f -> camera t
    t_tf = -np.einsum("...ij,...j->...i", R_tf, t_ft)
    with np.errstate(divide="ignore"):  # inverse depth: affine across a plane's image, so bilinear is exact
        img = 1.0 / np.asarray(depth_f, np.float64)[..., None]
    Hf, Wf = img.shape[:2]
    ok = np.isfinite(z)
    for _ in range(iters):
        Xf = np.einsum("...ij,...j->...i", R_ft, ray * z[..., None]) + t_ft  # the ray's point, in f
        with np.errstate(divide="ignore", invalid="ignore"):
            pu = K[0, 0] * Xf[..., 0] / Xf[..., 2] + K[0, 2]
            pv = K[1, 1] * Xf[..., 1] / Xf[..., 2] + K[1, 2]
        centres = (pu >= 0.5) & (pu <= Wf - 0.5) & (pv >= 0.5) & (pv <= Hf - 0.5)  # no extrapolation
        with np.errstate(divide="ignore"):
            Zf = np.where(centres, 1.0 / sample_bilinear(img, pu, pv)[..., 0], np.nan)
        Xs = np.stack([(pu - K[0, 2]) / K[0, 0], (pv - K[1, 2]) / K[1, 1], np.ones_like(pu)], -1) * Zf[..., None]
        z_new = (np.einsum("...ij,...j->...i", R_tf, Xs) + t_tf)[..., 2]
        ok = np.isfinite(z_new) & (Xf[..., 2] > 0)
        z = np.where(ok, z_new, np.nan)
    with np.errstate(invalid="ignore"):
        agree = np.abs(Zf - Xf[..., 2]) <= tol * Zf
    return np.where(ok & agree, z, np.nan)


def depth_at_time(u: np.ndarray, v: np.ndarray, K: np.ndarray, c2w_t: np.ndarray, w: np.ndarray,
                  frame_a: tuple[np.ndarray, np.ndarray], frame_b: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Depth at pixels (u, v) at times between two rendered frames a and b
    (each (c2w (4, 4), surface depth (H, W))), w in [0, 1] the times' share
    of the interval: :func:`depth_by_reprojection` from the nearer frame, else
    from the other; each guess starts at that frame's depth at the pixel."""
    u, v = np.asarray(u, np.float64), np.asarray(v, np.float64)
    iu = np.clip(np.floor(u).astype(np.int64), 0, frame_a[1].shape[1] - 1)
    iv = np.clip(np.floor(v).astype(np.int64), 0, frame_a[1].shape[0] - 1)
    za, zb = frame_a[1][iv, iu], frame_b[1][iv, iu]
    guess_a, guess_b = np.where(np.isfinite(za), za, zb), np.where(np.isfinite(zb), zb, za)
    near_a = np.asarray(w) < 0.5
    out = np.full(u.shape, np.nan)
    for first, second, g1, g2, sel in ((frame_a, frame_b, guess_a, guess_b, near_a),
                                       (frame_b, frame_a, guess_b, guess_a, ~near_a)):
        if not np.any(sel):
            continue
        us, vs = u[sel], v[sel]
        pose = c2w_t if np.ndim(c2w_t) == 2 else np.asarray(c2w_t)[sel]
        z = depth_by_reprojection(us, vs, K, pose, first[0], first[1], g1[sel])
        miss = ~np.isfinite(z)  # only these need the other frame
        if np.any(miss):
            z[miss] = depth_by_reprojection(us[miss], vs[miss], K, pose if np.ndim(pose) == 2 else pose[miss],
                                            second[0], second[1], g2[sel][miss])
        out[sel] = z
    return out


def encode_dsec_png(flow: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """DSEC's 16-bit flow image (H, W, 3) uint16 in RGB order (R = dx, G = dy,
    B = valid) from flow (H, W, 2) px and validity (H, W). Flow is rounded to
    1/128 px; a pixel whose flow exceeds DSEC_MAX_PX (about 256 px) or is
    not finite is written invalid, with zero flow, as DSEC writes invalid
    pixels. Write with :func:`gs2e.io.images.write_png` (it takes RGB)."""
    f = np.asarray(flow, np.float64)
    ok = np.asarray(valid, bool) & np.all(np.isfinite(f), axis=-1) & np.all(np.abs(f) <= DSEC_MAX_PX, axis=-1)
    q = np.where(ok[..., None], np.rint(np.where(ok[..., None], f, 0.0) * DSEC_SCALE) + DSEC_OFFSET,
                 DSEC_OFFSET)
    out = np.empty(f.shape[:2] + (3,), np.uint16)
    out[..., :2] = np.clip(q, 0, 65535).astype(np.uint16)
    out[..., 2] = ok
    return out


def decode_dsec_png(img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(flow (H, W, 2) float64 px, valid (H, W) bool) of a DSEC 16-bit flow
    image (H, W, 3) in RGB order (what imageio reads; OpenCV's imread gives
    BGR: reverse its channels first)."""
    img = np.asarray(img)
    flow = (img[..., :2].astype(np.float64) - DSEC_OFFSET) / DSEC_SCALE
    return flow, img[..., 2] > 0
