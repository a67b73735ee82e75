"""The whole trajectory stage for one scene, without I/O.

Base path (smoothing + velocity-controlled B-spline) timed by every preset in
``speed_presets`` (travelled back and forth up to ``min_duration_s``), plus G
mini-trajectories timed by ``mini_preset``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from gs2e.common.errors import InputError
from gs2e.common.log import timed
from gs2e.common.settings import require
from gs2e.io.scene import Scene
from gs2e.trajectory.curve import pose_deltas
from gs2e.trajectory.order import is_sequential, tour_order
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.trajectory import (SampledPath, Trajectory, achieved_steps_fine, back_and_forth,
                                        build_base_path,
                                        build_mini_paths, hermite_eval,
                                        preset_duration_s, image_steps_width, timed_trajectory,
                                        points_in_view_fraction,
                                        timestamps_us)
from gs2e.trajectory.velocity import make_profile

log = logging.getLogger("gs2e.trajectory")


@dataclass
class StageResult:
    trajectories: dict[str, Trajectory]
    input_c2w: np.ndarray          # (N, 4, 4) input poses
    base: SampledPath


def _intrinsics(scene: Scene) -> list[np.ndarray]:
    """(3, 3) K per input frame, as the virtual camera uses it: the frame's own
    when it has the scene's size (W, H: the most common view size and
    orientation), else the median of those frames' (a portrait view of a
    landscape-dominated capture lends its pose, not its camera)."""
    size = (int(scene.width), int(scene.height))
    main = scene.main_K()
    Ks = [f.camera.K if scene.frame_size(i) == size else main for i, f in enumerate(scene.frames)]
    if any(f.camera.dist and any(abs(x) > 0 for x in f.camera.dist) for f in scene.frames):
        log.warning("input cameras have distortion; trajectories use their pinhole part")
    return Ks


def camera_choice(scene: Scene) -> dict:
    """How the virtual camera was chosen (recorded in every trajectory's meta)."""
    n_main, n = len(scene.main_frames()), len(scene.frames)
    return {"camera_size": [int(scene.width), int(scene.height)],
            "camera_rule": f"the most common view size and orientation ({n_main} of {n} views); "
                           "views of other sizes lend their poses with those views' median intrinsics"}


def _nearest_input(base: SampledPath, j: int) -> int:
    """Index of the input frame nearest (in curve parameter) to dense pose j."""
    if len(base.knot_index) == 1:
        return int(base.knot_index[0])
    u = float(hermite_eval(base.arc.L, base.arc.u, base.arc.du, np.array([base.s[j]]))[0])
    k = int(np.argmin(np.abs(base.curve.breaks - u)))
    return int(base.knot_index[min(k, len(base.knot_index) - 1)])


def _speed_meta(path: SampledPath, alpha: float, beta_n: float) -> dict:
    """Largest relative per-step deviation of the travelled arc length from the
    requested one: measured along the path (sub-steps) and as frame-to-frame chords."""
    req = np.diff(path.s)
    out = {}
    for key, got in (("max_rel_step_error", achieved_steps_fine(path, alpha, beta_n)),
                     ("max_rel_step_error_chord", pose_deltas(path.c2w, alpha, beta_n))):
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(req > 0, np.abs(got / req - 1.0), 0.0)
        out[key] = float(rel.max()) if rel.size else 0.0
    return out


def generate(scene: Scene, cfg: TrajectorySettings, seed: int, timings: dict | None = None) -> StageResult:
    """All trajectories of one scene.

    Parameters
    ----------
    scene : a posed scene (frames in sequence order, c2w in OpenCV axes).
    cfg : the ``trajectory`` settings.
    seed : seed of the mini-trajectory draws (same seed, same output).
    """
    cfg = require(cfg, TrajectorySettings, "generate")
    if not scene.has_poses:
        raise InputError("trajectory: scene has frames without poses (run sfm first)")
    c2w_in = scene.c2w_array()
    Ks = _intrinsics(scene)
    method = cfg.view_order
    if method == "auto":
        method = "sequence" if is_sequential(scene) else "tour"
    order = np.arange(len(c2w_in))
    if method == "tour":
        order = tour_order(c2w_in, float(cfg.alpha), float(cfg.beta), bool(cfg.normalize_translation))
        c2w_in = c2w_in[order]
        Ks = [Ks[i] for i in order]
    log.info("view order: %s", method)
    if any(np.abs(K - Ks[0]).max() > 1e-6 * max(1.0, np.abs(Ks[0]).max()) for K in Ks):
        log.info("input intrinsics differ between frames; base trajectory uses frame 0's")
    profile = make_profile(cfg.velocity, cfg.speed_list, cfg.speed_list_tau)
    with timed("base trajectory", log, timings):
        base = build_base_path(c2w_in, cfg, profile, what="scene poses")
    alpha, beta_n = base.info["alpha"], base.info["beta_per_scene_unit"]
    scale = base.info["translation_scale"]
    common = {"alpha": alpha, "beta": float(cfg.beta), "translation_scale": scale,
              "fps_base": float(cfg.fps_base)}
    out: dict[str, Trajectory] = {}
    base_meta = {k: v for k, v in base.info.items() if k != "v"}
    base_meta.update(common, **camera_choice(scene), kind="base", method=cfg.interpolation, view_order=method,
                     view_order_names=[scene.frames[i].name for i in order],
                     velocity=None if cfg.speed_list else cfg.velocity,
                     speed_list=cfg.speed_list, **_speed_meta(base, alpha, beta_n))
    points = scene.points_xyz if scene.points_xyz is not None and len(scene.points_xyz) else None
    if points is None:
        log.info("no sparse points: speed presets use their angular / linear speed limits")

    def image_steps(c2w: np.ndarray, K: np.ndarray) -> np.ndarray | None:
        return None if points is None else image_steps_width(c2w, K, scene.width, scene.height, points)

    base_steps = image_steps(base.c2w, Ks[0])
    if base_steps is not None:
        base_meta["image_step_width_median"] = float(np.median(base_steps))
    for name in cfg.speed_presets:
        preset = cfg.presets[name]
        dur = preset_duration_s(base.c2w, preset, scale, cfg.fps_base, base_steps)
        t_us = timestamps_us(dur, len(base.s))
        # (the requested profile is not repeated here: diff(s) is proportional to v(t_j))
        meta = dict(base_meta, preset=name, preset_values=dict(preset))
        tr = timed_trajectory(base, t_us, Ks[0], scene.width, scene.height, meta)
        if cfg.min_duration_s:
            tr = back_and_forth(tr, int(round(float(cfg.min_duration_s) * 1e6)))
            if tr.meta.get("legs"):
                log.info("base_%s: %.3f s one way, travelled back and forth over %.2f legs (%.3f s)",
                         name, dur, tr.meta["legs"], tr.duration_us * 1e-6)
        out[f"base_{name}"] = tr
    with timed("mini-trajectories", log, timings):
        rng = np.random.default_rng(int(seed))
        sees, min_sees = None, 0.0
        if points is not None and int(cfg.mini_groups) > 0:
            def sees(c2w: np.ndarray) -> np.ndarray:
                return points_in_view_fraction(points, c2w, Ks[0], scene.width, scene.height)

            # the base path's poorest view (at most 256 of its poses) sets the bar
            stride = max(1, len(base.c2w) // 256)
            min_sees = float(cfg.mini_min_view) * float(sees(base.c2w[::stride]).min())
        minis = build_mini_paths(base, cfg, rng, alpha, beta_n, sees, min_sees)
        preset = cfg.presets[cfg.mini_preset]
        for g, (path, j0) in enumerate(minis):
            src = _nearest_input(base, j0)
            dur = preset_duration_s(path.c2w, preset, scale, cfg.fps_base, image_steps(path.c2w, Ks[src]))
            t_us = timestamps_us(dur, len(path.s))
            meta = {k: v for k, v in path.info.items() if k != "v"}
            meta.update(common, **camera_choice(scene), kind="mini", group=g, seed=int(seed),
                        preset=cfg.mini_preset,
                        preset_values=dict(preset), intrinsics_from_frame=src,
                        **_speed_meta(path, alpha, beta_n))
            out[f"mini{g:02d}_{cfg.mini_preset}"] = timed_trajectory(
                path, t_us, Ks[src], scene.width, scene.height, meta)
    return StageResult(out, c2w_in, base)
