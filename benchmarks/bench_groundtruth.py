"""Benchmark: optical flow, IMU and ROS bags on trained real scenes, and the optical-flow task.

Runs the workflow on demo, temple_ring, llff_fern and mouse_colmap at
DAVIS346 (base trajectories at mild, medium and strong; export.formats flow,
imu, rosbag; bench.tasks flow; 2000 training steps), cached under
benchmarks/results/bench_groundtruth_cache/, then measures, per scene and
speed:

* per-event flow: its depth reprojected from the frames against the depth
  rendered at the time (relative endpoint error p50 / p95, share kept valid);
* warp: the photometric error (grey, 8-bit levels) of frame t+1 sampled at
  each valid pixel's ground-truth flow target against frame t, and of frame
  t+1 at the same pixel (no warp), pooled over the trajectory's frame pairs;
  ``warp_gain`` = no warp / warp (target >= 5);
* valid: the share of opaque pixels (alpha >= 0.5) with valid forward flow
  (target >= 90 % at mild);
* the flow task: contrast maximisation's and zero flow's AEE (target: CM
  lower at every speed), and its CPU against the scene's (target <= 10 %);
* costs from the jobs' own logs: flow + IMU exports against the render job
  (target <= 10 %), the ROS bag against the events job (target <= 1/4).

Every job's CPU is the exact figure its log ends with. Writes
benchmarks/results/bench_groundtruth.csv and .png; the headline is last.

    python benchmarks/bench_groundtruth.py [--quick] [--scenes demo,temple_ring,...]
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from harness import REPO, RESULTS, SHARED_SCENES, parser, pyplot, report, save_plot, write_csv

CACHE = RESULTS / "bench_groundtruth_cache"
SPEEDS = ("mild", "medium", "strong")
COMMON = ("events.sensor=davis346;splat.max_iterations=2000;bench.tasks=[flow];"
          "export.formats=[flow,imu,rosbag];bench.video_learned=[]")
SCENES = {
    "demo": ("demo", "", ""),
    "temple_ring": (SHARED_SCENES["temple_ring"][0], str(SHARED_SCENES["temple_ring"][1]), ""),
    "llff_fern": (SHARED_SCENES["llff_fern"][0], str(SHARED_SCENES["llff_fern"][1]), ""),
    # its own COLMAP cameras (a 56-view phone capture; SfM is not what is measured here)
    "mouse_colmap": (SHARED_SCENES["mouse_colmap"][0], str(SHARED_SCENES["mouse_colmap"][1]),
                     "sfm.reuse_poses=true;ingest.max_side=640"),
}
# (the demo's own cameras: COLMAP registers too few of its views at 128 x 96)
QUICK = ("demo.width=128;demo.height=96;sfm.reuse_poses=true;splat.max_iterations=300;"
         "render.trajectories=[base_mild];events.max_duration_s=0.3")


def build(names: list[str], quick: bool, rebuild: bool) -> Path:
    """The workflow's results for ``names``, cached: missing outputs are made;
    with ``rebuild`` also those whose config or code changed (Snakemake's
    params and code triggers; a code version changes with any edit of a
    stage's imports, so by default a cached build is kept)."""
    wd = CACHE / ("quick" if quick else "full")
    wd.mkdir(parents=True, exist_ok=True)
    trajs = "render.trajectories=[" + ",".join(f"base_{s}" for s in SPEEDS) + "]"
    rows = ["scene_id\tlayout\tpath\toverrides"]
    for n in names:
        layout, path, over = SCENES[n]
        if layout != "demo" and not Path(path).exists():
            raise SystemExit(f"{path} is missing (../shared/data): cannot benchmark {n}")
        over = ";".join(x for x in (COMMON, trajs, over, QUICK if quick else "") if x)
        rows.append(f"{n}\t{layout}\t{path}\t{over}")
    (wd / "scenes.tsv").write_text("\n".join(rows) + "\n")
    env = dict(os.environ, GS2E_PROGRESS="0",
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    subprocess.run([str(Path(sys.executable).parent / "snakemake"), "--snakefile", str(REPO / "Snakefile"),
                    "--cores", "2", "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}",
                    "results_dir=results", "--rerun-triggers", "mtime", "input",
                    *(["params", "code"] if rebuild else [])], check=True, env=env)
    return wd / "results"


def _grey(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def warp_and_valid(scene_dir: Path, traj: str) -> dict:
    """Pooled warp errors and the valid share of opaque pixels of one trajectory
    (module docstring), from its flow export."""
    import h5py
    import hdf5plugin  # noqa: F401  (flow.h5 is Blosc-compressed, as events.h5)

    from gs2e.export.source import TrajectorySource
    from gs2e.groundtruth.flow import pixel_centres, sample_bilinear

    src = TrajectorySource(scene_dir, traj)
    e_warp = e_none = 0.0
    n = n_opaque = n_valid = 0
    with h5py.File(scene_dir / "export" / "flow" / traj / "flow.h5") as f:
        fw, ok = f["forward_flow_px"], f["forward_valid"]
        u, v = pixel_centres(src.width, src.height)
        for i in range(fw.shape[0]):
            a, b = _grey(src.image("rgb", i)), _grey(src.image("rgb", i + 1))
            flow, valid = fw[i].astype(np.float64), ok[i].astype(bool)
            warped = sample_bilinear(b[..., None], u + flow[..., 0], v + flow[..., 1])[..., 0]
            e_warp += float(np.abs(warped - a)[valid].sum())
            e_none += float(np.abs(b - a)[valid].sum())
            n += int(valid.sum())
            opaque = src.alpha(i) >= 0.5
            n_opaque += int(opaque.sum())
            n_valid += int((valid & opaque).sum())
    return {"warp_err": e_warp / max(n, 1), "nowarp_err": e_none / max(n, 1),
            "warp_gain": (e_none / e_warp) if e_warp > 0 else math.inf,
            "valid_of_opaque": n_valid / max(n_opaque, 1)}


def event_flow_error(scene_dir: Path, traj: str, n_times: int = 8) -> dict:
    """How far the per-event flow's depth (reprojected from the nearer frame:
    gs2e.groundtruth.flow.depth_at_time) puts its flow from the flow with the
    depth rendered at the event's time: at ``n_times`` times between frames,
    over every pixel a surface covers then; relative endpoint error (p50, p95)
    and the share of those pixels the per-event rule keeps valid."""
    from gs2e.export.flow import camera_velocities
    from gs2e.export.source import TrajectorySource
    from gs2e.groundtruth.flow import (ALPHA_MIN, depth_at_time, motion_field, pixel_centres,
                                       surface_depth)
    from gs2e.render.renderer import TrajectoryRenderer

    src = TrajectorySource(scene_dir, traj)
    t = src.frames["t_us"].to_numpy()
    r = TrajectoryRenderer(scene_dir / "splat", src.trajectory_file,
                           sensor=((src.width, src.height), "cover"))
    K = src.K(0)
    u, v = pixel_centres(src.width, src.height)
    errs, kept = [], []
    for i in np.unique(np.linspace(0, len(t) - 2, n_times).round().astype(int)):
        w = 0.37  # a time inside the interval, away from both frames
        te = t[i] + w * (t[i + 1] - t[i])
        c2w = r.pose(te)
        _, alpha, depth = r.render_pose(c2w)
        v_c, w_c = camera_velocities(src, np.array([te]))
        exact = motion_field(surface_depth(depth, alpha, ALPHA_MIN), K, v_c[0], w_c[0])
        frames = [(src.c2w([j])[0], surface_depth(src.depth(j), src.alpha(j), ALPHA_MIN)) for j in (i, i + 1)]
        z = depth_at_time(u, v, K, c2w, np.full(u.shape, w), *frames)
        approx = motion_field(z, K, v_c[0], w_c[0])
        ok_exact = np.all(np.isfinite(exact), axis=-1)
        both = ok_exact & np.all(np.isfinite(approx), axis=-1)
        mag = np.linalg.norm(exact[both], axis=-1)
        errs.append(np.linalg.norm(approx[both] - exact[both], axis=-1) / np.maximum(mag, 1e-9))
        kept.append(both.sum() / max(ok_exact.sum(), 1))
    e = np.concatenate(errs)
    return {"event_flow_rel_err_p50": float(np.median(e)), "event_flow_rel_err_p95": float(np.percentile(e, 95)),
            "event_flow_kept": float(np.mean(kept))}


def costs(scene_dir: Path, traj: str) -> dict:
    """CPU seconds of the trajectory's jobs from their logs, and the scene's total."""
    from gs2e.report.io import read_job_usage

    logs = scene_dir / "logs"

    def cpu(name: str) -> float:
        u = read_job_usage(logs / f"{name}.log")
        return u["cpu_s"] if u else math.nan

    total = sum((read_job_usage(p) or {"cpu_s": 0.0})["cpu_s"] for p in logs.glob("*.log"))
    return {"render_cpu_s": cpu(f"render_{traj}"), "events_cpu_s": cpu(f"events_{traj}"),
            "flow_cpu_s": cpu(f"export_flow_{traj}"), "imu_cpu_s": cpu(f"export_imu_{traj}"),
            "bag_cpu_s": cpu(f"export_rosbag_{traj}"), "task_cpu_s": cpu(f"bench_flow_{traj}"),
            "scene_cpu_s": total}


def flow_task(scene_dir: Path, traj: str) -> dict:
    import pandas as pd

    df = pd.read_parquet(scene_dir / "bench" / "flow" / f"{traj}.parquet")
    m = df.groupby("method")[["aee_px", "out_3px"]].mean()
    return {"aee_zero_px": float(m.loc["zero", "aee_px"]), "aee_cm_px": float(m.loc["contrast_max", "aee_px"]),
            "out3_zero": float(m.loc["zero", "out_3px"]), "out3_cm": float(m.loc["contrast_max", "out_3px"]),
            "pairs": int((df["method"] == "zero").sum())}


def main() -> None:
    ap = parser(__doc__, quick="the demo scene small and short, mild only (a few minutes)")
    ap.add_argument("--scenes", default=",".join(SCENES), help="comma-separated, from: " + ", ".join(SCENES))
    ap.add_argument("--rebuild", action="store_true",
                    help="rerun the cached workflow's jobs whose config or code changed")
    args = ap.parse_args()
    names = ["demo"] if args.quick else args.scenes.split(",")
    results = build(names, args.quick, args.rebuild)
    rows = []
    for n in names:
        for sp in (SPEEDS[:1] if args.quick else SPEEDS):
            traj = f"base_{sp}"
            sd = results / n
            st = __import__("json").loads((sd / "events" / traj / "stats.json").read_text())["stats"]
            r = {"scene": n, "speed": sp, "duration_s": st["duration_s"], **warp_and_valid(sd, traj),
                 **event_flow_error(sd, traj), **flow_task(sd, traj), **costs(sd, traj)}
            r["flow_imu_of_render"] = (r["flow_cpu_s"] + r["imu_cpu_s"]) / r["render_cpu_s"]
            r["bag_of_events"] = r["bag_cpu_s"] / r["events_cpu_s"]
            rows.append(r)
    for n in names:  # the task's share of the scene: all its trajectories' flow jobs
        mine = [r for r in rows if r["scene"] == n]
        share = sum(r["task_cpu_s"] for r in mine) / mine[0]["scene_cpu_s"]
        for r in mine:
            r["task_of_scene"] = share
    files = [write_csv("bench_groundtruth", rows)]
    plt = pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(10, 3.6))
    labels = [f"{r['scene']}\n{r['speed']}" for r in rows]
    x = np.arange(len(rows))
    a1.bar(x - 0.2, [r["aee_zero_px"] for r in rows], 0.4, color="tab:gray", label="zero flow")
    a1.bar(x + 0.2, [r["aee_cm_px"] for r in rows], 0.4, color="tab:blue", label="contrast max.")
    a1.set_xticks(x, labels, fontsize=7)
    a1.set(ylabel="AEE (px)", title="optical-flow task")
    a1.legend()
    a2.bar(x, [r["warp_gain"] for r in rows], color="tab:green")
    a2.axhline(5, color="k", ls=":")
    a2.set_xticks(x, labels, fontsize=7)
    a2.set(ylabel="error without warp / with", title="ground-truth flow: photometric check")
    files.append(save_plot(fig, "bench_groundtruth"))
    cols = ["scene", "speed", "duration_s", "warp_gain", "valid_of_opaque", "event_flow_rel_err_p50",
            "aee_zero_px", "aee_cm_px", "flow_imu_of_render", "bag_of_events", "task_of_scene"]
    lines = ["  ".join(f"{c:>14}" for c in cols)]
    for r in rows:
        lines.append("  ".join(f"{r[c]:>14.3f}" if isinstance(r[c], float) else f"{r[c]:>14}" for c in cols))
    mild = [r for r in rows if r["speed"] == "mild"]
    head = (f"warp gain >= {min(r['warp_gain'] for r in rows):.1f}x (target 5); valid at mild >= "
            f"{min(r['valid_of_opaque'] for r in mild):.1%} (90 %); CM beats zero in "
            f"{sum(r['aee_cm_px'] < r['aee_zero_px'] for r in rows)}/{len(rows)}; flow+IMU <= "
            f"{max(r['flow_imu_of_render'] for r in rows):.1%} of render (10 %); bag <= "
            f"{max(r['bag_of_events'] for r in rows):.2f}x events (0.25); flow task <= "
            f"{max(r['task_of_scene'] for r in rows):.1%} of the scene (10 %)")
    report("\n".join(lines), head, files)


if __name__ == "__main__":
    main()
