"""The motion clock (events.sampling.mode = motion) on hard scenes: a thin
occluder crossing a textured background, a semi-transparent edge, pure
rotation, a camera moving toward a surface, a Gaussian next to the near
plane; each against a dense reference (samples 0.02 px apart) with the ideal
model. And the measure it runs on (gs2e.splat.forward.image_motion_px),
which the fixed clock reports per sample."""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.events.models import Events, IdealModel
from gs2e.events.sampling import SamplerStats, image_luminance, motion_times
from gs2e.events.settings import event_settings
from gs2e.splat.forward import ForwardRenderer, image_motion_px

W, H, F = 64, 48, 60.0
EPS, THETA = 1e-3, 0.2


def _gaussians(xyz, rgb, scale, opacity_logit=6.0):
    from gs2e.splat.init import rgb_to_sh_dc

    xyz = np.asarray(xyz, float)
    n = len(xyz)
    return {"means": xyz, "quats": np.tile([1.0, 0, 0, 0], (n, 1)),
            "log_scales": np.log(np.broadcast_to(np.asarray(scale, float), (n, 3))).copy(),
            "opacity_logits": np.broadcast_to(np.asarray(opacity_logit, float), (n,)).copy(),
            "sh": rgb_to_sh_dc(np.broadcast_to(np.asarray(rgb, float), (n, 3)))[:, None, :]}


def _merge(*gs):
    return {k: np.concatenate([g[k] for g in gs]) for k in gs[0]}


def _wall(depth=4.0, n=40, extent=3.0, seed=0):
    """A randomly coloured wall of round Gaussians at z = depth."""
    rng = np.random.default_rng(seed)
    xs = (np.arange(n) - n / 2 + 0.5) * (2 * extent / n)
    X, Y = np.meshgrid(xs, xs)
    return _gaussians(np.c_[X.ravel(), Y.ravel(), np.full(n * n, depth)],
                      rng.uniform(0.05, 0.95, (n * n, 3)), extent / n)


def _pose(tx=0.0, ty=0.0, tz=0.0, yaw=0.0):
    c2w = np.eye(4)
    c, s = np.cos(yaw), np.sin(yaw)
    c2w[:3, :3] = [[c, 0, s], [0, 1, 0], [-s, 0, c]]
    c2w[:3, 3] = tx, ty, tz
    return c2w


SCENES = {
    # a thin bar at 1 m sweeping across a wall at 4 m: it occludes and uncovers texture
    "thin_occluder": (lambda: _merge(_wall(), _gaussians(np.c_[np.zeros(24), np.linspace(-0.5, 0.5, 24),
                                                                 np.ones(24)], [0.95, 0.95, 0.95], 0.012)),
                      lambda t: _pose(tx=-0.05 + 1.0 * t)),
    # a half-plane of translucent grey (alpha 0.3) in front of the wall
    "translucent_edge": (lambda: _merge(_wall(), _gaussians(
        np.c_[np.repeat(np.linspace(0.0, 1.5, 16), 16), np.tile(np.linspace(-1.0, 1.0, 16), 16),
              np.full(256, 2.0)], [0.9, 0.9, 0.9], 0.06, opacity_logit=-0.85)),
        lambda t: _pose(tx=-0.3 + 3.0 * t)),
    "pure_rotation": (lambda: _wall(), lambda t: _pose(yaw=6.0 * t)),
    "toward_surface": (lambda: _wall(depth=2.0), lambda t: _pose(tz=30.0 * t)),
    # a large dim Gaussian 5 cm in front of the camera, sliding sideways
    "near_plane": (lambda: _merge(_wall(), _gaussians([[0.0, 0.0, 0.05]], [0.3, 0.3, 0.3], 0.02,
                                                     opacity_logit=0.0)),
                   lambda t: _pose(tx=-0.01 + 0.6 * t)),
}
SPAN_US = 30_000


def _clock(r, pose_of_s, bound_px, dt_max_us=5000, stats=None):
    return list(motion_times(lambda t: r.centres(pose_of_s(t * 1e-6)), image_motion_px, 0, SPAN_US,
                             bound_px, 1, dt_max_us, 400, stats))


def _events(r, pose_of_s, times):
    lum = np.empty((len(times), H, W), np.float32)
    for i, t in enumerate(times):
        image_luminance(r.render(pose_of_s(t * 1e-6)), lum[i])
    return _ideal(list(zip(times, lum)))


def _ideal(frames):
    """Ideal events of (t_us, (H, W) luminance) frames."""
    ts = np.array([t for t, _ in frames], np.int64)
    m = IdealModel((H, W), theta_on=THETA, theta_off=THETA, log_eps=EPS)
    m.start(int(ts[0]), frames[0][1])
    return Events.concat([m.process_batch(ts[1:], np.stack([f for _, f in frames[1:]])), m.flush()])


def _l1(ev, ref):
    def counts(e):
        return np.bincount((e.y.astype(np.int64) * W + e.x) * 2 + e.p, minlength=2 * H * W)
    return np.abs(counts(ev) - counts(ref)).sum() / max(1, len(ref))


@pytest.mark.parametrize("scene", list(SCENES))
def test_motion_clock_bounds_motion_and_matches_a_dense_reference(scene):
    make, pose_of_s = SCENES[scene]
    r = ForwardRenderer(make(), 0, F, F, W / 2, H / 2, W, H)
    st = SamplerStats()
    times = _clock(r, pose_of_s, 0.25, stats=st)
    assert times[0] == 0 and times[-1] == SPAN_US and np.all(np.diff(times) > 0)
    assert st.forced == 0
    proj = [r.centres(pose_of_s(t * 1e-6)) for t in times]
    steps = [image_motion_px(a, b) for a, b in zip(proj, proj[1:])]
    assert max(steps) <= 0.25
    # steps as long as the bound allows (growth is at most 2x per step)
    assert len(times) <= 2 * sum(steps) / 0.25 + 12
    ref_times = _clock(r, pose_of_s, 0.02, dt_max_us=250)
    ref = _events(r, pose_of_s, ref_times)
    ev = _events(r, pose_of_s, times)
    assert len(ref) > 300, "the scene makes events"
    # the ideal model takes log-intensity as linear between samples: at a
    # quarter pixel per sample, some crossings of a dense texture land late,
    # across the span's end, or are split between neighbours
    assert abs(len(ev) - len(ref)) <= 0.02 * len(ref)
    assert _l1(ev, ref) <= 0.03


@pytest.mark.parametrize("scene", list(SCENES))
def test_curve_clock_matches_a_dense_reference_on_the_continuous_renderer(scene):
    """mode: curve (issue 67) on the same scenes, rendered continuous in time
    (smooth window, depth orders held at knots 2 px apart): steps set by
    the cubic's measured error (error_fraction 0.05 of theta = 0.2), 4
    points per step on it, against the same renderer's dense reference
    (0.02 px apart, a line between renders). Measured: within 0.4 % of its
    count and a per-pixel L1 of at most 0.004, on 2-10 % of its renders."""
    from gs2e.events.rendered import cubic_substeps
    from gs2e.events.sampling import adaptive_samples
    from gs2e.splat.forward import ContinuousRenderer, order_knots

    make, pose_of_s = SCENES[scene]
    r = ForwardRenderer(make(), 0, F, F, W / 2, H / 2, W, H, window="smooth")

    def pose(t):
        return pose_of_s(t * 1e-6)

    cr = ContinuousRenderer(r, pose, order_knots(r, pose, 0, SPAN_US, 2.0), SPAN_US)
    lum = {}

    def render_log(t):
        lum[t] = np.empty((H, W), np.float32)
        image_luminance(cr.render(t), lum[t])
        return np.log(lum[t].astype(np.float64) + EPS)

    ref_times = _clock(r, pose_of_s, 0.02, dt_max_us=250)
    ref = _ideal([(t, (np.exp(render_log(t)) - EPS).astype(np.float32)) for t in ref_times])
    lum.clear()
    st = SamplerStats()
    times = [t for t, _ in adaptive_samples(render_log, 0, SPAN_US, 0.05 * THETA, 1, 5000, 400, st,
                                            outlier_fraction=0.001, degree=3)]
    frames = [(t, lum[t]) for t in times]
    ev = _ideal([frames[0], *cubic_substeps(iter(frames[1:]), 4, EPS, frames[0])])
    assert len(ref) > 300 and st.forced == 0
    assert len(times) <= 0.12 * len(ref_times)
    assert abs(len(ev) - len(ref)) <= 0.01 * len(ref)
    assert _l1(ev, ref) <= 0.01


def test_near_plane_gaussian_does_not_drive_the_clock():
    """A Gaussian 5 cm in front of the camera moves its centre 80x faster
    than the wall, but it is 24 px wide: its image changes as if it moved 24x
    less, and that is what the clock follows."""
    make, pose_of_s = SCENES["near_plane"]
    g = make()
    r = ForwardRenderer(g, 0, F, F, W / 2, H / 2, W, H)
    a, b = r.centres(pose_of_s(0.0)), r.centres(pose_of_s(0.001))
    near = len(g["means"]) - 1
    raw = np.hypot(*(b.uv[near] - a.uv[near]))
    wall = np.hypot(*(b.uv[:-1] - a.uv[:-1]).T)[a.seen[:-1]].max()
    assert raw > 50 * wall and a.seen[near] and a.scale_px[near] > 20
    assert image_motion_px(a, b) == pytest.approx(raw / a.scale_px[near], rel=0.05)
    assert image_motion_px(a, b) < raw / 20


def test_motion_of_a_still_camera_is_zero_and_steps_grow_to_the_largest():
    r = ForwardRenderer(_wall(), 0, F, F, W / 2, H / 2, W, H)
    p = r.centres(_pose())
    assert image_motion_px(p, r.centres(_pose())) == 0.0
    times = list(motion_times(lambda t: r.centres(_pose()), image_motion_px, 0, 100_000, 0.25, 10,
                              8000, 400))
    assert times[-1] == 100_000 and np.diff(times)[-4:-1].tolist() == [8000] * 3


def test_motion_clock_forces_a_jump_and_rejects_bad_arguments():
    """A pose that jumps cannot be bounded: the step at dt_min is taken and counted."""
    r = ForwardRenderer(_wall(), 0, F, F, W / 2, H / 2, W, H)
    st = SamplerStats()
    times = list(motion_times(lambda t: r.centres(_pose(tx=0.0 if t < 5000 else 0.2)),
                              image_motion_px, 0, 10_000, 0.25, 50, 5000, 400, st))
    assert st.forced == 1 and times[-1] == 10_000
    jump = [b - a for a, b in zip(times, times[1:]) if a < 5000 <= b]
    assert jump == [50]
    with pytest.raises(ValueError):
        next(motion_times(lambda t: None, image_motion_px, 0, 10, 0.0, 1, 5))


def test_several_threshold_crossings_between_two_samples():
    """A pixel whose log rises by 3.5 thresholds between two samples gets three
    ON events at the linearly interpolated times."""
    m = IdealModel((1, 1), theta_on=THETA, theta_off=THETA, log_eps=EPS)
    l0 = 0.1
    m.start(0, np.full((1, 1), l0, np.float32))
    l1 = (l0 + EPS) * np.exp(3.5 * THETA) - EPS
    ev = Events.concat([m.process_batch(np.array([1000]), np.full((1, 1, 1), l1, np.float32)),
                        m.flush()])
    assert ev.p.tolist() == [1, 1, 1]
    np.testing.assert_allclose(ev.t, [1000 * k / 3.5 for k in (1, 2, 3)], atol=1.0)


def test_rendered_source_in_motion_mode_renders_at_its_clock(tmp_path):
    """mode: motion through the workflow's event source: whole frames at the
    clock's times, each the true render at its time, fewer where the bound is
    looser; a config without the bound is refused naming the key."""
    from gs2e.testing import plane_model, straight_trajectory

    from gs2e.common.errors import ConfigError
    from gs2e.config import check_config, load_config
    from gs2e.events.rendered import RenderedSource

    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 0.2)

    def source(px):
        cfg = load_config({"events": {"model": "ideal", "sampling": {
            "mode": "motion", "max_motion_px": px, "dt_max_us": 1_000_000}}})
        return RenderedSource(model, traj, event_settings(check_config(cfg)["events"]), span_us=None)

    runs = {}
    for px in (0.25, 1.0):
        src = source(px)
        t0, f0 = src.start()
        ts, frames = zip(*[(t.copy(), f.copy()) for t, f in src.batches()])
        ts, frames = np.concatenate(ts), np.concatenate(frames)
        assert ts[-1] == src.t1_us and np.all(np.diff(np.r_[t0, ts]) > 0)
        assert src.stats.forced == 0 and src.stats.max_change <= px
        ref = np.empty(src.shape, np.float32)
        for i in (0, len(ts) // 2, len(ts) - 1):
            image_luminance(src.renderer.render(src.pose_at(int(ts[i]))), ref)
            np.testing.assert_array_equal(frames[i], ref)
        runs[px] = len(ts)
    assert runs[1.0] < 0.5 * runs[0.25]
    with pytest.raises(ConfigError, match="events.sampling.max_motion_px"):
        check_config(load_config({"events": {"sampling": {"mode": "motion"}}}))


def test_fixed_clock_reports_how_far_the_image_moves_per_sample(tmp_path, caplog):
    """mode: fixed measures the image motion between its samples: on a camera
    panning over a plane of sub-pixel Gaussians every centre moves
    F |dx| / Z per step; stats.json carries the median and largest, and a
    clock coarse enough to move the image over STEP_MOTION_WARN_PX per
    sample logs a warning naming the setting that bounds it."""
    import json
    import logging

    from gs2e.config import check_config, load_config
    from gs2e.events.rendered import STEP_MOTION_WARN_PX, RenderedSource
    from gs2e.events.simulate import simulate_to_folder
    from gs2e.testing import PLANE_DEPTH, PLANE_F, plane_model, straight_trajectory

    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 0.2)
    for fps, span_s in ((2400.0, 0.2), (2.0, None)):  # the path pans ~3 px/s
        cfg = check_config(load_config({"events": {
            "model": "ideal", "preview": False, "max_duration_s": span_s,
            "sampling": {"mode": "fixed", "fixed_fps": fps}}}))
        src = RenderedSource(model, traj, event_settings(cfg["events"]))
        step_us = int(round(1e6 / fps))
        t_mid = (src.t0_us + src.t1_us - step_us) // 2
        dx = src.pose_at(t_mid + step_us)[0, 3] - src.pose_at(t_mid)[0, 3]
        expected = PLANE_F * abs(dx) / PLANE_DEPTH
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="gs2e.events"):
            stats = simulate_to_folder(src, event_settings(cfg["events"]), tmp_path / f"ev{int(fps)}", seed=0)
        on_disk = json.loads((tmp_path / f"ev{int(fps)}" / "stats.json").read_text())["stats"]
        p50, mx = on_disk["sampling_step_motion_px_p50"], on_disk["sampling_step_motion_px_max"]
        assert (p50, mx) == (stats["sampling_step_motion_px_p50"], stats["sampling_step_motion_px_max"])
        # constant speed in the middle of the path: the median is the analytic step
        assert p50 == pytest.approx(expected, rel=1e-3)
        assert p50 <= mx <= 1.05 * expected
        warned = [r for r in caplog.records if r.levelno == logging.WARNING and "bunch" in r.message]
        assert bool(warned) == (mx > STEP_MOTION_WARN_PX)
        if warned:
            assert "events.sampling" in warned[0].getMessage()
    assert mx > STEP_MOTION_WARN_PX, "the coarse clock moves the image more than the warning's bound"
