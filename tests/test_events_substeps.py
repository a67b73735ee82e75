"""Points between renders on a cubic (events.sampling.substeps, issue 67)."""

from __future__ import annotations

import math

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


def test_points_stay_within_what_a_render_holds():
    """A pixel that saturates (0.4, then 1.0 at every later render): the
    cubic through the renders overshoots past 1 between them, which the
    event models refuse as luminance; clamped at lum_max (the event source
    passes 1, or the light's largest scale), every point is a valid one and
    the renders pass unchanged. Found on temple_ring (1.00006)."""
    from gs2e.events.models import IdealModel

    vals = [0.02, 0.4, 1.0, 1.0, 1.0]
    frames = [(1000 * (i + 1), np.full((1, 2), v, np.float32)) for i, v in enumerate(vals)]
    free = list(cubic_substeps(iter(frames[1:]), 8, EPS, frames[0]))
    assert max(float(f.max()) for _, f in free) > 1.0  # the overshoot is real
    out = list(cubic_substeps(iter(frames[1:]), 8, EPS, frames[0], lum_max=1.0))
    assert max(float(f.max()) for _, f in out) == 1.0
    assert [t for t, _ in out] == [t for t, _ in free]
    m = IdealModel((1, 2), theta_on=0.2, theta_off=0.2, log_eps=EPS)
    m.start(frames[0][0], frames[0][1])
    m.process_batch(np.array([t for t, _ in out], np.int64), np.stack([f for _, f in out]))


def test_steps_shorter_than_the_points_skip_duplicates():
    out, frames = _run(2, 8, n=5)
    ts = [t for t, _ in out]
    assert ts == sorted(set(ts)) and set(t for t, _ in frames[1:]) <= set(ts)


def test_substeps_need_a_whole_image_mode():
    from gs2e.config import check_config

    with pytest.raises(ConfigError, match="substeps"):
        check_config(load_config({"events": {"sampling": {"mode": "tile", "substeps": 4}}}))
    check_config(load_config({"events": {"sampling": {"mode": "tile"}}}))  # null: none in tile


@pytest.mark.parametrize("sampling, points", [({}, 4), ({"mode": "fixed"}, 1), ({"mode": "tile"}, 1),
                                              ({"mode": "motion", "max_motion_px": 1.0}, 1),
                                              ({"substeps": 8}, 8), ({"mode": "fixed", "substeps": 2}, 2)])
def test_points_per_step_by_default_are_the_curve_clocks(sampling, points):
    """substeps null (the default): the cubic's 4 points per step in mode curve
    (the default mode), the renders alone in the others; a value given wins."""
    from gs2e.config import check_config
    from gs2e.events.settings import event_settings

    cfg = check_config(load_config({"events": {"sampling": sampling}}))
    assert cfg["events"]["sampling"]["substeps"] == sampling.get("substeps")  # recorded as given
    assert event_settings(cfg["events"]).sampling.substeps == points


def test_exact_slopes_make_a_cubic_exact_where_the_neighbours_do_not():
    """A cubic g(t) is reproduced to rounding by Hermite steps with its own
    derivative at each render; the neighbours' (Catmull-Rom) slopes miss it."""
    def g(t):
        x = (np.asarray(t, np.float64) - 1000.0) * 1e-4
        return np.stack([x ** 3 - 2 * x, 0.5 * x * x - 1.0], -1)[..., None, :] * 0.3

    def dg(t):  # per us
        x = (float(t) - 1000.0) * 1e-4
        return np.array([3 * x * x - 2, x], np.float64)[None, :] * 0.3e-4

    times = np.arange(21) * 1000 + 1000
    lum = {int(t): (np.exp(g(t)) - EPS).astype(np.float32) for t in times}
    # the signal's own derivative at each render
    exact = [(int(t), lum[int(t)], dg(t)) for t in times]
    guess = [(int(t), lum[int(t)]) for t in times]
    errs = {}
    for name, frames in (("exact", exact), ("neighbours", guess)):
        out = [(t, f) for t, f in cubic_substeps(iter(frames[1:]), 8, EPS, frames[0]) if t not in lum]
        errs[name] = max(np.abs(np.log(f.astype(np.float64) + EPS) - g(t)).max() for t, f in out)
    assert errs["exact"] < 1e-5 < 0.01 * errs["neighbours"], errs


def test_slopes_by_difference_need_substeps_and_a_model_continuous_in_time(tmp_path):
    from gs2e.config import check_config
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings
    from gs2e.testing import plane_model, straight_trajectory

    with pytest.raises(ConfigError, match="events.sampling.slopes=difference.*substeps"):
        check_config(load_config({"events": {"sampling": {"mode": "fixed", "slopes": "difference"}}}))
    check_config(load_config({"events": {"sampling": {"slopes": "difference"}}}))  # curve: 4 points
    slopes = {"events": {"model": "ideal", "sampling": {"mode": "fixed", "fixed_fps": 600.0, "substeps": 4,
                                                        "slopes": "difference"}}}
    with pytest.raises(ConfigError, match="slopes: difference needs .*splat.window: smooth"):
        check_config(load_config({**slopes, "splat": {"window": "cut"}}), workflow=True)
    check_config(load_config(slopes), workflow=True)  # the default window: smooth
    cfg = check_config(load_config(slopes))["events"]
    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 0.2)
    with pytest.raises(ConfigError, match=f"slopes: difference needs a model continuous in time.*{model}"):
        RenderedSource(model, traj, event_settings(cfg))


def test_slopes_by_difference_follow_the_continuous_render_between_renders(tmp_path):
    """A smooth-window plane panning by ~320 px/s, rendered at 600 fps with 4
    points per step: with each render's own slope the points lie closer to the
    true continuous render at their times than with the neighbours' slopes, and
    every step costs two renders."""
    import json

    from gs2e.config import check_config
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings
    from gs2e.testing import plane_model, straight_trajectory
    from gs2e.trajectory import fixed_times_us

    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 20.0)  # ~0.5 px per step
    info = json.loads((model / "model.json").read_text())
    (model / "model.json").write_text(json.dumps({**info, "window": "smooth"}))
    errs, renders = {}, {}
    for slopes in ("neighbours", "difference"):
        cfg = check_config(load_config({"events": {"model": "ideal", "sampling": {
            "mode": "fixed", "fixed_fps": 600.0, "substeps": 4, "slopes": slopes}}}))["events"]
        src = RenderedSource(model, traj, event_settings(cfg))
        mid = (src.t0_us + src.t1_us) // 2  # the camera over the plane's middle
        src = RenderedSource(model, traj, event_settings(cfg), span_us=(mid, mid + 50_000))
        src.start()
        ts, frames = zip(*[(t.copy(), f.copy()) for t, f in src.batches()])
        ts, frames = np.concatenate(ts), np.concatenate(frames)
        renders[slopes] = src.stats.renders
        truth = RenderedSource(model, traj, event_settings(cfg), span_us=(mid, mid + 50_000))
        renders_at = set(fixed_times_us(src.t0_us, src.t1_us, 600.0).tolist())
        e = []
        for t, f in zip(ts, frames):
            if int(t) not in renders_at:  # a point between renders
                ref = truth.frame(int(t))
                e.append(np.abs(np.log(f.astype(np.float64) + 1e-3) - np.log(ref.astype(np.float64) + 1e-3)))
        errs[slopes] = float(np.mean(np.concatenate([x.ravel() for x in e])))
    n_steps = 30  # 50 ms at 600 fps
    assert renders["neighbours"] == n_steps + 1 and renders["difference"] == 2 * (n_steps + 1)
    assert errs["difference"] < 0.5 * errs["neighbours"], errs


@pytest.mark.parametrize("cfa,light", [(None, None), ("RGGB", "sine"), (None, "square")])
def test_slopes_by_the_tangent_pass_are_the_renders_derivative(tmp_path, cfa, light):
    """``events.sampling.slopes: tangent``: each render's slope of log(L +
    log_eps) from the tangent pass, through the luminance (or a colour
    filter's channel) and a flickering light's scale, against a central
    difference of the rendered frames over +-8 us (float32 frames: their
    rounding bounds the agreement); no second render per step (a tangent pass
    each, counted apart); refused on a model of the cut window, naming it. A
    square wave's edge adds no slope (its jump is not a rate)."""
    import json

    from gs2e.config import check_config
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings
    from gs2e.light.settings import Condition
    from gs2e.testing import plane_model, straight_trajectory

    model, traj = plane_model(tmp_path), straight_trajectory(tmp_path, 20.0)
    ev = {"model": "ideal", "sampling": {"mode": "fixed", "fixed_fps": 600.0, "substeps": 4,
                                         "slopes": "tangent"}}
    if cfa:
        ev["cfa"] = cfa
    cfg = event_settings(check_config(load_config({"events": ev}))["events"])
    with pytest.raises(ConfigError, match=f"slopes: tangent needs a model continuous in time.*{model}"):
        RenderedSource(model, traj, cfg)
    with pytest.raises(ConfigError, match="slopes: tangent needs .*splat.window: smooth"):
        check_config(load_config({"events": ev, "splat": {"window": "cut"}}), workflow=True)
    info = json.loads((model / "model.json").read_text())
    (model / "model.json").write_text(json.dumps({**info, "window": "smooth"}))
    cond = (Condition("flicker", 500.0, 500.0, None, 0.5, 0.0, 100.0, 0.3, light) if light else None)
    src = RenderedSource(model, traj, cfg, light=cond)
    mid = (src.t0_us + src.t1_us) // 2
    src = RenderedSource(model, traj, cfg, light=cond, span_us=(mid, mid + 20_000))
    src.start()
    edge = src.light.t0_us + 5_000 * math.ceil((mid - src.light.t0_us) / 5_000) if light else None
    for t in (edge + 1_003, edge + 3_117) if light else (mid + 1_003, mid + 9_117):
        g = {d: np.log(src.frame(t + d).astype(np.float64) + src.log_eps) for d in (-8, 8)}
        fd = (g[8] - g[-8]) / 16.0
        tan = src.tangent_log_slope(t)
        assert np.abs(fd).max() > 1e-4  # the plane moves under the camera
        assert np.abs(tan - fd).max() < 0.02 * np.abs(fd).max(), np.abs(tan - fd).max()
    if light == "square":  # at the edge (100 Hz: every 5 ms of the path) as 1 ms after it
        assert np.abs(src.tangent_log_slope(edge)).max() < 2 * np.abs(src.tangent_log_slope(edge + 1_000)).max()
    src = RenderedSource(model, traj, cfg, light=cond, span_us=(mid, mid + 20_000))
    src.start()
    n = sum(len(ts) for ts, _ in src.batches())
    assert src.stats.renders == 13 and src.stats.tangents == 13 and n == 12 * 4
