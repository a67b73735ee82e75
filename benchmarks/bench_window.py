"""Benchmark: the smooth compositing window against 3DGS's cut one (issue 67).

Issue 67 makes the renderer continuous in time: each Gaussian's alpha tapered
to zero with its slope at its cut, the weights faded before a pixel stops
(``splat.window: smooth``, :mod:`gs2e.splat.raster`), and the depth order
held at knots and cross-faded (:class:`gs2e.splat.forward.ContinuousRenderer`).
The images of a model change, so the issue asks what that costs: held-out
PSNR within 0.1 dB of the cut window's (or within the seeds' spread), and
training CPU at most 1.1x.

Per scene, the model is trained twice in this run, with the cut and the smooth
window, from the same SfM scene, seed and settings as the workflow's (the
``train`` command of the scene's workflow log in the cache of
bench_groundtruth.py: 2,000 steps at the DAVIS346 size), and scored on the
held-out views with its own window. Render cost per frame at the DAVIS346
camera along ``base_mild`` (process CPU ms, float32, the event stage's
renderer): the cut model with the cut window; the smooth model with the
smooth window and a per-render sort; with the continuous renderer
(orders cross-faded between knots ``render.order_step_px`` = 2 px apart);
and the continuous renderer's tangent pass (the image and its exact time
derivative, float64: :mod:`gs2e.splat.tangent`).

Scenes: demo, temple_ring, llff_fern, mouse_colmap, as cached by
``bench_groundtruth.py`` (run it first). ``--quick``: demo only.
``--seed-offset k`` trains with the workflow's seed + k (another draw, for
the seeds' spread; its own cache and CSV).

Usage: python benchmarks/bench_window.py [--quick] [--scenes demo,temple_ring] [--seed-offset 1]
Writes benchmarks/results/bench_window[_quick].csv and .png; the last line
printed is the headline.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys

import numpy as np

import harness

CACHE = harness.RESULTS / "bench_window_cache"
SOURCE = harness.RESULTS / "bench_groundtruth_cache" / "full" / "results"
WINDOWS = ("cut", "smooth")


def train_command(scene: str) -> list[str]:
    """The workflow's ``gs2e train`` arguments for ``scene`` (its log's first line)."""
    line = (SOURCE / scene / "logs" / "train.log").read_text().splitlines()[0]
    m = re.search(r"--seed (\d+) .*--target-size (\S+) --config-json (\{.*\})$", line)
    if not m:
        raise SystemExit(f"{SOURCE / scene / 'logs' / 'train.log'}: no train command (run bench_groundtruth.py)")
    return [m.group(1), m.group(2), m.group(3)]


def train(scene: str, window: str, seed_offset: int = 0) -> dict:
    """Train (cached) and return the model's train_stats.json."""
    out = CACHE / scene / (window + (f"_seed{seed_offset}" if seed_offset else ""))
    if not (out / "model.json").exists():
        seed, size, cfg = train_command(scene)
        seed = str(int(seed) + seed_offset)
        cfg = json.dumps({**json.loads(cfg), "window": window, "checkpoint_every": 0})
        shutil.rmtree(out, ignore_errors=True)
        out.parent.mkdir(parents=True, exist_ok=True)
        print(f"training {scene} with the {window} window ...", flush=True)
        subprocess.run([sys.executable, "-m", "gs2e", "train", "--scene", str(SOURCE / scene / "sfm"),
                        "--out", str(out), "--seed", seed, "--threads", "2", "--scene-id", scene,
                        "--no-resume", "--checkpoint-dir", str(out.with_name(f".{out.name}.ckpt")),
                        "--target-size", size, "--config-json", cfg],
                       check=True, env=harness.gs2e_env(harness.REPO), stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
    return json.loads((out / "train_stats.json").read_text())


def render_costs(scene: str, reps: int) -> dict:
    """Median process CPU ms per frame of the three renders (module docstring)."""
    from gs2e.common.camera import render_camera
    from gs2e.splat.forward import ContinuousRenderer, ForwardRenderer, order_knots
    from gs2e.splat.model import load_model
    from gs2e.trajectory import load_trajectory

    traj = load_trajectory(SOURCE / scene / "trajectories" / "base_mild.npz")
    K, W, H = render_camera(np.asarray(traj.K), traj.width, traj.height, 1.0, ((346, 260), "cover"))

    def pose(t):
        return traj.pose_at(np.array([float(t)]))[0]

    t0, t1 = float(traj.t_us[0]), float(traj.t_us[-1])
    times = np.linspace(t0 + 0.3 * (t1 - t0), t0 + 0.7 * (t1 - t0), reps)
    out = {}
    for window in WINDOWS:
        p, info = load_model(CACHE / scene / window)
        r = ForwardRenderer(p, int(info["sh_degree"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H,
                            window=window)
        r.render(pose(times[0]))  # compiles
        out[f"{window}_render_ms"] = harness.median_cpu_ms(
            lambda it=iter(np.tile(times, 3)): r.render(pose(next(it))), reps)
        if window == "smooth":
            cr = ContinuousRenderer(r, pose, order_knots(r, pose, t0, t1, 2.0), t1)
            cr.render(times[0])
            r.tiles_blended, r.renders = 0, 0
            out["continuous_render_ms"] = harness.median_cpu_ms(
                lambda it=iter(np.tile(times, 3)): cr.render(next(it)), reps)
            out["tiles_blended_share"] = r.tiles_blended / max(1, r.renders) / r.n_tiles
            cr.render_tangent(times[0])  # compiles
            out["tangent_pass_ms"] = harness.median_cpu_ms(
                lambda it=iter(np.tile(times, 3)): cr.render_tangent(next(it)), reps)
    return out


def plot(df):
    plt = harness.pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(df))
    ax[0].bar(x - 0.2, df.cut_psnr, 0.4, label="cut")
    ax[0].bar(x + 0.2, df.smooth_psnr, 0.4, label="smooth")
    ax[0].set_ylabel("held-out PSNR (dB)")
    ax[0].set_ylim(min(df.cut_psnr.min(), df.smooth_psnr.min()) - 2, None)
    for k, (col, lab) in enumerate((("train_cpu_ratio", "training CPU"),
                                    ("smooth_render_ratio", "render, smooth window"),
                                    ("continuous_render_ratio", "render, continuous"))):
        ax[1].bar(x + (k - 1) * 0.27, df[col], 0.27, label=lab)
    ax[1].axhline(1.0, color="k", lw=0.8)
    ax[1].set_ylabel("CPU / cut window's")
    for a in ax:
        a.set_xticks(x, df.scene)
        a.legend(fontsize=8)
    fig.tight_layout()
    return fig


def main() -> None:
    import pandas as pd

    ap = harness.parser(__doc__, quick="the demo only (about 6 min with training)")
    ap.add_argument("--scenes", default="demo,temple_ring,llff_fern,mouse_colmap")
    ap.add_argument("--reps", type=int, default=15, help="renders timed per renderer")
    ap.add_argument("--seed-offset", type=int, default=0, help="train with the workflow's seed + this")
    args = ap.parse_args()
    scenes = ["demo"] if args.quick else args.scenes.split(",")
    rows = []
    with harness.clock() as total:
        for scene in scenes:
            st = {w: train(scene, w, args.seed_offset) for w in WINDOWS}
            rc = render_costs(scene, args.reps) if not args.seed_offset else {}
            rows.append({"scene": scene, "machine": harness.machine(),
                         **{f"{w}_psnr": st[w]["test_psnr"] for w in WINDOWS},
                         **{f"{w}_ssim": st[w]["test_ssim"] for w in WINDOWS},
                         **{f"{w}_train_cpu_s": st[w]["train_cpu_s"] for w in WINDOWS},
                         **{f"{w}_gaussians": st[w]["n_gaussians"] for w in WINDOWS},
                         **rc})
            r = rows[-1]
            r["psnr_delta_db"] = r["smooth_psnr"] - r["cut_psnr"]
            r["train_cpu_ratio"] = r["smooth_train_cpu_s"] / r["cut_train_cpu_s"]
            if rc:
                r["smooth_render_ratio"] = r["smooth_render_ms"] / r["cut_render_ms"]
                r["continuous_render_ratio"] = r["continuous_render_ms"] / r["cut_render_ms"]
                r["tangent_pass_ratio"] = r["tangent_pass_ms"] / r["cut_render_ms"]
            print(f"{scene}: PSNR cut {r['cut_psnr']:.2f} smooth {r['smooth_psnr']:.2f} dB", flush=True)
    df = pd.DataFrame(rows)
    name = "bench_window" + ("_quick" if args.quick else "") + (f"_seed{args.seed_offset}" if args.seed_offset else "")
    csv = harness.write_csv(name, df.to_dict("records"))
    print(f"measured in {total.wall_s:.0f} s on {harness.machine()}")
    if args.seed_offset:
        table = df[["scene", "cut_psnr", "smooth_psnr", "psnr_delta_db", "train_cpu_ratio"]].round(3)
        harness.report(table, f"seed + {args.seed_offset}: smooth against cut, held-out PSNR "
                       f"{df.psnr_delta_db.min():+.2f} to {df.psnr_delta_db.max():+.2f} dB", [csv])
        return
    png = harness.save_plot(plot(df), name)
    table = df[["scene", "cut_psnr", "smooth_psnr", "psnr_delta_db", "cut_gaussians", "smooth_gaussians",
                "train_cpu_ratio", "cut_render_ms", "smooth_render_ms", "continuous_render_ms",
                "tiles_blended_share", "tangent_pass_ms"]].round(3)
    head = (f"smooth window against cut: held-out PSNR {df.psnr_delta_db.min():+.2f} to "
            f"{df.psnr_delta_db.max():+.2f} dB, training CPU {df.train_cpu_ratio.min():.2f}-"
            f"{df.train_cpu_ratio.max():.2f}x, render {df.smooth_render_ratio.min():.2f}-"
            f"{df.smooth_render_ratio.max():.2f}x, continuous render (orders cross-faded) "
            f"{df.continuous_render_ratio.min():.2f}-{df.continuous_render_ratio.max():.2f}x, "
            f"its tangent pass {df.tangent_pass_ratio.min():.2f}-{df.tangent_pass_ratio.max():.2f}x "
            f"({len(df)} scenes)")
    harness.report(table, head, [csv, png])


if __name__ == "__main__":
    main()
