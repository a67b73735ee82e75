"""Benchmark of the trajectory stage.

Figures (issue 4):
  1. time per interpolated pose for M = 1e4, 1e5, 1e6 dense poses from a 30-view
     scene, on one core: the whole dense-path construction (smoothing, fit,
     arc-length table, velocity profile, reparameterisation, evaluation) and the
     evaluation alone (Trajectory.pose_at on M sorted times);
  2. the whole stage for a 30-view scene (gamma=5, 3 speed presets, G=3
     mini-trajectories of F=150): compute, file writing, the plot, and a cold
     `gs2e trajectory` process;
  3. accuracy: the largest relative per-step deviation of the achieved arc length
     from the requested profile (independently measured by 32 sub-steps, on 2000
     steps spread along the path).

Baseline, measured in the same run: the paper's recipe done the obvious way with
SciPy -- make_interp_spline on the centres, scipy RotationSpline on the
rotations, both parameterised by the cumulative displacement s and sampled at the
reparameterised targets (no true arc-length inversion).

Usage: python benchmarks/bench_trajectory.py [--quick]
Writes benchmarks/results/bench_trajectory.csv and .png; last line = headline.
"""

from __future__ import annotations

import os

for _v in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")  # one core

import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from gs2e.common.so3 import geodesic_angle  # noqa: E402
from gs2e.io.scene import write_scene_json  # noqa: E402
from gs2e.testing import TEMPLE, make_scene, ring, temple_c2w  # noqa: E402
from gs2e.trajectory.curve import pose_deltas, smooth_poses, translation_scale  # noqa: E402
from gs2e.trajectory.io import write_outputs  # noqa: E402
from gs2e.trajectory.settings import TrajectorySettings  # noqa: E402
from gs2e.trajectory.stage import generate  # noqa: E402
from gs2e.trajectory.trajectory import (build_base_path, timed_trajectory,  # noqa: E402
                                        timestamps_us)
from gs2e.trajectory.velocity import parse_velocity_expression, reparameterise  # noqa: E402
from harness import (REPO, best_s, clock, gs2e_env, parser, pyplot, report,  # noqa: E402
                     save_plot, write_csv)


def best_of(fn, reps):
    """(fastest wall s, median wall s, the last call's result) over ``reps``
    calls of ``fn()`` (no warm-up); :func:`harness.best_s` where only the
    fastest is needed."""
    ts = []
    res = None
    for _ in range(reps):
        with clock() as t:
            res = fn()
        ts.append(t.wall_s)
    return min(ts), float(np.median(ts)), res


def baseline_dense(c2w_in, cfg, v):
    """Paper recipe with SciPy: splines in the displacement parameter s, sampled
    at the velocity-reparameterised s targets (returns (M,4,4))."""
    from scipy.interpolate import make_interp_spline
    from scipy.spatial.transform import Rotation, RotationSpline

    sm = smooth_poses(c2w_in, cfg.smooth_half_width)
    scale = translation_scale(sm)
    d = pose_deltas(sm, cfg.alpha, cfg.beta / scale)
    s = np.concatenate([[0.0], np.cumsum(d)])
    N = len(sm)
    M = int(np.ceil(cfg.gamma * N - 1e-9))
    t = np.linspace(0, 1, M)
    st = reparameterise(v(t), s[-1])
    pos = make_interp_spline(s, sm[:, :3, 3], k=3)(st)
    rot = RotationSpline(s, Rotation.from_matrix(sm[:, :3, :3]))(st).as_matrix()
    out = np.zeros((M, 4, 4))
    out[:, :3, :3] = rot
    out[:, :3, 3] = pos
    out[:, 3, 3] = 1
    return out


def fine_step_error(c2w_fn, s_targets, alpha, beta_n, n=32, n_steps=2000):
    """Max relative deviation of the achieved per-step arc length (measured by n
    sub-steps of a function s -> poses) from the requested steps, over n_steps
    steps spread evenly along the path; the ratio achieved/requested is compared
    with its median, so a global scale error does not count (only the shape)."""
    j = np.unique(np.linspace(0, len(s_targets) - 2, n_steps).round().astype(int))
    a, b = s_targets[j], s_targets[j + 1]
    ss = (a[:, None] + (b - a)[:, None] * np.linspace(0, 1, n + 1)[None]).ravel()
    P = c2w_fn(ss).reshape(len(a), n + 1, 4, 4)
    ang = geodesic_angle(P[:, :-1, :3, :3], P[:, 1:, :3, :3]).sum(1)
    lin = np.linalg.norm(np.diff(P[:, :, :3, 3], axis=1), axis=2).sum(1)
    r = (alpha * ang + beta_n * lin) / (b - a)
    return float(np.max(np.abs(r / np.median(r) - 1)))


def main() -> None:
    args = parser(__doc__, quick="fewer repetitions (< 60 s)").parse_args()
    reps = 3 if args.quick else 7
    real = TEMPLE.exists()
    c2w = temple_c2w(30) if real else ring(30, noise=0.01)
    scene_name = "temple_ring (30 of 47 real views)" if real else "synthetic ring (30 views)"
    cfg = TrajectorySettings.defaults()
    v = parse_velocity_expression(cfg.velocity)
    rows = []

    # warm-up: numba cache load / compile
    build_base_path(c2w, cfg.replace(gamma=5), v)

    print(f"scene: {scene_name}; one core; best of {reps}")
    print(f"{'M':>9} {'build us/pose':>14} {'pose_at us/pose':>16} {'scipy us/pose':>14} "
          f"{'ratio':>7} {'speed err ours':>15} {'speed err scipy':>16}")
    for M in (10_000, 100_000, 1_000_000):
        c = cfg.replace(gamma=M / 30)
        tb, tb_med, p = best_of(lambda: build_base_path(c2w, c, v), reps)
        tr = timed_trajectory(p, timestamps_us(10.0, len(p.s)), np.eye(3), 1, 1, {})
        tq = best_s(lambda: tr.pose_at(tr.t_us), reps)
        tbase = best_s(lambda: baseline_dense(c2w, c, v), max(1, reps // 2))
        # accuracy on 2000 steps spread along the path (the measure itself is costly)
        from gs2e.trajectory.trajectory import eval_at_s
        err_ours = fine_step_error(lambda s: eval_at_s(p.curve, p.arc, s), p.s,
                                   p.info["alpha"], p.info["beta_per_scene_unit"])
        err_base = baseline_step_error(c2w, c, v)
        rows.append({"M": M, "build_s": tb, "build_s_median": tb_med,
                     "build_us_per_pose": tb / M * 1e6, "pose_at_us_per_pose": tq / M * 1e6,
                     "scipy_us_per_pose": tbase / M * 1e6, "speedup_vs_scipy": tbase / tb,
                     "speed_err_ours": err_ours, "speed_err_scipy": err_base})
        r = rows[-1]
        print(f"{M:>9} {r['build_us_per_pose']:>14.4f} {r['pose_at_us_per_pose']:>16.4f} "
              f"{r['scipy_us_per_pose']:>14.4f} {r['speedup_vs_scipy']:>6.1f}x "
              f"{err_ours:>15.2e} {err_base:>16.2e}")
        p = tr = None  # frees the 1e6-pose arrays before the next size

    # whole stage
    scene = make_scene(c2w, 640, 480)
    sc = cfg
    generate(scene, sc, 0)
    t_gen, t_gen_med, res = best_of(lambda: generate(scene, sc, 0), reps)
    with tempfile.TemporaryDirectory() as td:
        t_write = best_s(lambda: write_outputs(Path(td) / "o", res, sc, "s", plot=False), reps)
        t_plot = best_s(lambda: write_outputs(Path(td) / "p", res, sc, "s", plot=True), max(1, reps // 2))
        (Path(td) / "scene").mkdir()
        write_scene_json(scene, Path(td) / "scene")
        with clock() as t:
            r = subprocess.run([sys.executable, "-m", "gs2e", "trajectory", "--scene",
                                str(Path(td) / "scene"), "--out", str(Path(td) / "cli")],
                               env=gs2e_env(REPO), capture_output=True, text=True)
        t_cli = t.wall_s
        assert r.returncode == 0, r.stderr
    n_poses = sum(len(t.t_us) for t in res.trajectories.values())
    print(f"\nwhole stage, 30 views, gamma=5, presets {cfg.speed_presets}, "
          f"G={cfg.mini_groups} x F={cfg.mini_frames} ({len(res.trajectories)} trajectories, "
          f"{n_poses} poses):")
    print(f"  compute (generate)      {t_gen * 1e3:8.1f} ms  (median {t_gen_med * 1e3:.1f} ms)")
    print(f"  + write npz/json        {t_write * 1e3:8.1f} ms")
    print(f"  write incl. plot        {t_plot * 1e3:8.1f} ms")
    print(f"  cold CLI process        {t_cli * 1e3:8.1f} ms  (imports, numba cache load, plot)")
    paper_s = 45.0
    stage = {"M": "stage", "stage_compute_s": t_gen, "stage_write_s": t_write,
             "stage_write_plot_s": t_plot, "cli_wall_s": t_cli,
             "paper_stage_s": paper_s}
    rows.append(stage)

    # one column per key of any row (sorted), empty where a row lacks it
    keys = sorted({k for r in rows for k in r})
    csv_path = write_csv("bench_trajectory", [{k: r.get(k, "") for k in keys} for r in rows])
    png = plot(rows, scene_name)
    print()
    r6 = rows[2]
    report(None, f"trajectory: {r6['build_us_per_pose']:.3f} us/pose at M=1e6 (target 0.2, paper 0.5; "
                 f"scipy baseline {r6['scipy_us_per_pose']:.2f} us = {r6['speedup_vs_scipy']:.0f}x slower); "
                 f"whole stage {t_gen:.3f} s compute, {t_gen + t_write:.3f} s with files "
                 f"(target 1 s, paper ~45 s = {paper_s / (t_gen + t_write):.0f}x)", [csv_path, png])


def baseline_step_error(c2w, c, v):
    """Speed error of the SciPy recipe (splines in s, no arc-length inversion)."""
    from scipy.interpolate import make_interp_spline
    from scipy.spatial.transform import Rotation, RotationSpline

    sm = smooth_poses(c2w, c.smooth_half_width)
    scale = translation_scale(sm)
    beta_n = c.beta / scale
    d = pose_deltas(sm, c.alpha, beta_n)
    s = np.concatenate([[0.0], np.cumsum(d)])
    M = int(np.ceil(c.gamma * len(sm) - 1e-9))
    st = reparameterise(v(np.linspace(0, 1, M)), s[-1])
    ps = make_interp_spline(s, sm[:, :3, 3], k=3)
    rs = RotationSpline(s, Rotation.from_matrix(sm[:, :3, :3]))

    def fn(x):
        out = np.zeros((len(x), 4, 4))
        out[:, :3, :3] = rs(x).as_matrix()
        out[:, :3, 3] = ps(x)
        out[:, 3, 3] = 1
        return out

    return fine_step_error(fn, st, c.alpha, beta_n)


def plot(rows, scene_name) -> Path:
    """The figure, saved as benchmarks/results/bench_trajectory.png; its path."""
    plt = pyplot()
    rr = [r for r in rows if r["M"] != "stage"]
    Ms = [r["M"] for r in rr]
    fig, (a0, a1) = plt.subplots(1, 2, figsize=(11, 4.2))
    a0.loglog(Ms, [r["build_us_per_pose"] for r in rr], "o-", label="gs2e: whole dense path")
    a0.loglog(Ms, [r["pose_at_us_per_pose"] for r in rr], "s-", label="gs2e: pose_at only")
    a0.loglog(Ms, [r["scipy_us_per_pose"] for r in rr], "^-", label="SciPy baseline")
    a0.axhline(0.2, color="g", ls="--", label="target 0.2 us")
    a0.axhline(0.5, color="r", ls=":", label="paper < 0.5 us")
    a0.set_xlabel("poses M")
    a0.set_ylabel("us per pose (one core)")
    a0.set_title(f"time per interpolated pose ({scene_name})", fontsize=9)
    a0.legend(fontsize=8)
    a1.semilogy(Ms, [r["speed_err_ours"] for r in rr], "o-", label="gs2e (true arc length)")
    a1.semilogy(Ms, [r["speed_err_scipy"] for r in rr], "^-", label="SciPy baseline (spline in s)")
    a1.axhline(1e-3, color="g", ls="--", label="requirement 1e-3")
    a1.set_xscale("log")
    a1.set_xlabel("poses M")
    a1.set_ylabel("max relative per-step speed error")
    a1.set_title("achieved vs requested speed profile", fontsize=9)
    a1.legend(fontsize=8)
    return save_plot(fig, "bench_trajectory", dpi=90)


if __name__ == "__main__":
    main()
