"""The compositing kernels on the cost model's trained real models (issue 32):
today's against a baseline revision's, in one run.

Runs on the models that ``bench_cost_model.py --run SCENE --sensor S`` trained
(``benchmarks/results/cost_<sensor>/results/<scene>/``):

* ``kernel``: along ``--poses`` poses of a trajectory, the forward kernel alone
  (the same tile lists for all) at the event camera's size as the event stage
  renders it (float32 storage): the baseline revision's kernel (float64
  compute), today's float64 kernel and today's float32 one (what the event and
  render stages now run), and the baseline's float32 kernel where it has one
  (``baseline_f32``); and at the training size the forward and backward a
  training step runs, baseline against today, in float64 and float32 (and the
  baseline's float32 passes where it has them). Per kernel: ms per call
  (median, 2 threads), and the image against the baseline's (largest
  difference, PSNR; 8-bit values that differ).
* ``render``: the whole ``gs2e render`` command the cost run's job ran (its log's
  command line), at ``--render-fps`` frames per second instead (fewer frames,
  the same exposure, so the same sub-frames per frame), today and in the
  baseline checkout: CPU seconds per blurred frame, and the 8-bit frames
  against the baseline's.
* ``events``: the whole ``gs2e events`` command (paper settings, fixed 2400 fps,
  first ``--span-s`` of the trajectory), today and in a checkout of the
  baseline revision, seeds 0 and 1 each: CPU seconds per simulated second and
  event statistics. DVS-Voltmeter is stochastic, so the yardstick is the spread
  between seeds (per-pixel count distance, :func:`event_runs.count_distance`).

Usage:
    python benchmarks/bench_compositing.py --sensor imx636 --scenes mouse_colmap
    python benchmarks/bench_compositing.py --sensor davis346 --scenes temple_ring,llff_fern
Writes benchmarks/results/bench_compositing_<sensor>_{kernel,events,render}.csv and
bench_compositing_<sensor>.png; the last printed line is the headline.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from contextlib import nullcontext
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np

import harness
from event_runs import PAPER_FPS, cost_run, count_distance, pixel_counts, run_events, scenes_of_cost_run
from harness import REPO, median_ms

BASELINE_REV = "468d5aa"  # main before the float32 kernel


def baseline_module(rev: str, tmp: Path):
    """gs2e/splat/raster.py of ``rev`` as a module of its own (compiled here)."""
    src = harness.baseline_source(rev, "gs2e/splat/raster.py")
    path = tmp / f"raster_{rev}.py"
    path.write_text(src.replace("cache=True", "cache=False"))
    spec = importlib.util.spec_from_file_location(f"raster_{rev}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _agreement(img: np.ndarray, ref: np.ndarray) -> dict:
    from gs2e.io.images import to_u8

    d = np.abs(img.astype(np.float64) - ref.astype(np.float64))
    mse = float(np.mean(d ** 2))
    return {"max_abs": float(d.max()), "psnr_db": float("inf") if mse == 0 else -10 * np.log10(mse),
            "frac_u8_differ": float(np.mean(to_u8(img) != to_u8(ref)))}


def bench_kernel(results: Path, events_cfg: dict, scene: str, traj: str, n_poses: int, reps: int,
                 base, tmp: Path) -> list[dict]:
    import numba
    import torch

    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings
    from gs2e.splat import raster as R
    from gs2e.splat.forward import TILE
    from gs2e.splat.model import load_model, render
    from gs2e.splat.rasterize import SplatCamera

    numba.set_num_threads(2)
    src = RenderedSource(results / scene / "splat", results / scene / "trajectories" / f"{traj}.npz",
                         event_settings(events_cfg))
    fr = src.renderer
    rows = []
    t_us = np.linspace(src.t0_us, src.t1_us, n_poses).astype(np.int64)
    for k, t in enumerate(t_us):
        fr.render(src.pose_at(int(t)))  # projects into fr's buffers
        offsets, gids = R.bin_gaussians(fr.means2d, fr.depths, fr.radii, fr.width, fr.height, TILE,
                                        fr.opac)
        tiles = np.arange(fr.n_tiles, dtype=np.int64)
        sched = R.tile_schedule(offsets)
        imgs = {}
        kernels = [("baseline", base.raster_forward_kernel)]
        if hasattr(base, "raster_forward_kernel_f32"):  # revisions with a float32 kernel
            kernels.append(("baseline_f32", base.raster_forward_kernel_f32))
        for label, kern in kernels + [("float64", R.raster_forward_kernel),
                                      ("float32", R.raster_forward_kernel_f32)]:
            out = np.zeros((fr.height, fr.width, 3), np.float32)
            T = np.zeros((fr.height, fr.width), np.float32)
            nc = np.zeros((fr.height, fr.width), np.int32)
            ms = median_ms(lambda: kern(tiles, offsets, gids, fr.m2_dt, fr.cn_dt, fr.opac_dt,
                                         fr.colors, fr.bg, fr.width, fr.height, TILE, out, T, nc,
                                         *sched), reps)
            imgs[label] = out
            rows.append({"scene": scene, "pass": "render forward", "kernel": label, "pose": k,
                         "width": fr.width, "height": fr.height, "n_gaussians": fr.n_gaussians,
                         "n_pairs": int(gids.shape[0]), "ms": ms,
                         **_agreement(out, imgs["baseline"]),
                         "same_bits_as_baseline_f32": (bool(np.array_equal(out, imgs["baseline_f32"]))
                                                       if "baseline_f32" in imgs else None)})
        print(f"  {scene} pose {k} {fr.width}x{fr.height}: "
              + ", ".join(f"{r['kernel']} {r['ms']:.1f} ms" for r in rows[-len(imgs):])
              + f"; float32 vs baseline {rows[-1]['psnr_db']:.1f} dB, max |d| {rows[-1]['max_abs']:.2e}",
              flush=True)
    # training size: forward (float64 compute) + backward, with gradients
    stats = json.loads((results / scene / "splat" / "train_stats.json").read_text())
    W = int(stats["train_width"])  # the height follows from the trajectory camera's aspect
    params, info = load_model(results / scene / "splat")
    p = {key: v.detach().float().requires_grad_(True) for key, v in params.items()}
    K = src.traj.K
    s = W / src.traj.width
    captured = {}
    real_bwd = R.rasterize_backward

    def spy(*a, **kw):
        captured["args"] = a
        return real_bwd(*a, **kw)

    for k, t in enumerate(t_us[: max(1, n_poses // 2)]):
        cam = SplatCamera.from_c2w(src.pose_at(int(t)), K[0, 0] * s, K[1, 1] * s, K[0, 2] * s,
                                   K[1, 2] * s, W, round(src.traj.height * s))
        R.rasterize_backward = spy
        try:
            img, alpha, depth, _ = render(p, cam, torch.zeros(3), int(info["sh_degree"]), "cpu")
            (img.sum() + depth.mean()).backward()
        finally:
            R.rasterize_backward = real_bwd
        m2, cn, op, feats, w, h, offsets, gids, out_T, nc, g_out, g_T, tile = captured["args"][:13]
        bg = np.zeros(feats.shape[1], feats.dtype)
        res = {}
        passes = [("baseline", base, None)]
        if hasattr(base, "raster_backward_kernel_f32"):  # revisions that train in float32
            passes.append(("baseline_f32", base, np.float32))
        for label, mod, dt in passes + [("float64", R, None), ("float32", R, np.float32)]:
            kw = {} if dt is None else {"compute_dtype": dt}
            fwd = lambda: mod.rasterize_forward(m2, cn, op, feats, bg, w, h, offsets, gids, tile, **kw)
            ms_f = median_ms(fwd, reps)
            o, oT, onc = fwd()  # the backward follows its own forward's stops
            bwd = lambda: mod.rasterize_backward(m2, cn, op, feats, w, h, offsets, gids, oT, onc,
                                                 g_out, g_T, tile, **kw)
            ms_b = median_ms(bwd, reps)
            res[label] = (o, bwd())
            same = all(np.array_equal(a, b) for a, b in zip(res[label], res["baseline"]))
            g, g0 = res[label][1], res["baseline"][1]
            # gradient agreement with the baseline, per column relative to its largest value
            scale = np.maximum(np.abs(g0).max(axis=0), 1e-30)
            rel = float(np.median(np.quantile(np.abs(g - g0), 0.99, axis=0) / scale))
            for pss, ms in (("train forward", ms_f), ("train backward", ms_b)):
                rows.append({"scene": scene, "pass": pss, "kernel": label, "pose": k, "width": w,
                             "height": h, "n_gaussians": int(m2.shape[0]), "n_pairs": int(gids.shape[0]),
                             "ms": ms, "same_bits_as_baseline": same, "grad_q99_rel": rel})
        r0, r64, r32 = rows[-2 * len(res):-2 * len(res) + 2], rows[-4:-2], rows[-2:]
        f32_same = ""
        if "baseline_f32" in res:
            r0f = rows[-6:-4]
            f32_same = (f"; float32 {r0f[0]['ms']:.1f} -> {r32[0]['ms']:.1f} ms forward, "
                        f"{r0f[1]['ms']:.1f} -> {r32[1]['ms']:.1f} ms backward, same bits as the "
                        f"baseline's float32: "
                        f"{all(np.array_equal(a, b) for a, b in zip(res['float32'], res['baseline_f32']))}")
        print(f"  {scene} training size {w}x{h} pose {k}: forward {r0[0]['ms']:.1f} -> "
              f"{r64[0]['ms']:.1f} (float64) / {r32[0]['ms']:.1f} ms (float32), backward "
              f"{r0[1]['ms']:.1f} -> {r64[1]['ms']:.1f} / {r32[1]['ms']:.1f} ms; float64 same "
              f"bits: {r64[1]['same_bits_as_baseline']}; float32 gradients: q99 of |diff| "
              f"{r32[1]['grad_q99_rel']:.1e} of each column's largest{f32_same}", flush=True)
    return rows


def bench_events(results: Path, events_cfg: dict, scene: str, traj: str, span_s: float,
                 baseline_repo: Path) -> list[dict]:
    rows, counts = [], {}
    with tempfile.TemporaryDirectory(prefix="bench_compositing_") as tmp:
        for label, repo in (("baseline", baseline_repo), ("today", REPO)):
            # numba compiles into each checkout's cache on its first run: not timed
            run_events(results / scene, traj, events_cfg, "fixed", PAPER_FPS, 1.0, 0, 0.002,
                       Path(tmp) / f"warm_{label}", repo=repo)
            for seed in (0, 1):
                r = run_events(results / scene, traj, events_cfg, "fixed", PAPER_FPS, 1.0, seed, span_s,
                               Path(tmp) / f"{label}_{seed}", repo=repo)
                st = r["stats"]
                counts[(label, seed)] = pixel_counts(r["events"], st["width"], st["height"])
                rows.append({"scene": scene, "trajectory": traj, "code": label, "seed": seed,
                             "width": st["width"], "height": st["height"], "span_s": st["duration_s"],
                             "n_events": st["n_events"], "on_fraction": st["on_fraction"],
                             "cpu_s": r["cpu_s"], "wall_s": r["wall_s"],
                             "cpu_s_per_s": r["cpu_s"] / st["duration_s"],
                             "source_s": st["source_s"], "model_s": st["model_s"]})
                print(f"  {scene} {label} seed {seed}: {st['n_events']:,} events, ON {st['on_fraction']:.4f}, "
                      f"{r['cpu_s']:.1f} CPU-s ({rows[-1]['cpu_s_per_s']:.0f} per simulated s)", flush=True)
    for row in rows:
        other = "today" if row["code"] == "baseline" else "baseline"
        row.update(count_dist_seeds=count_distance(counts[(row["code"], 0)], counts[(row["code"], 1)]),
                   count_dist_same_seed_other_code=count_distance(counts[(row["code"], row["seed"])],
                                                                  counts[(other, row["seed"])]))
    return rows


def render_command(scene_dir: Path, traj: str) -> list[str]:
    """The arguments of the ``gs2e render`` the cost run's job ran (its log's first line)."""
    import shlex

    log = scene_dir / "logs" / f"render_{traj}.log"
    first = log.read_text().splitlines()[0]
    # the line joins the arguments with spaces: the JSON (last) is the rest of the line
    head, _, cfg_json = first.split(" gs2e ", 1)[1].split(" ", 1)[1].partition(" --config-json ")
    args = shlex.split(head) + ["--config-json", cfg_json]
    if args[0] != "render" or not cfg_json:
        raise SystemExit(f"{log}: not a gs2e render log")
    return args


def bench_render(results: Path, scene: str, traj: str, fps: float, baseline_repo: Path) -> list[dict]:
    from gs2e.io.images import read_image

    args = render_command(results / scene, traj)
    i = args.index("--config-json")
    cfg = json.loads(args[i + 1])
    cfg["fps"] = fps
    args[i + 1] = json.dumps(cfg)
    rows, blur = [], {}
    with tempfile.TemporaryDirectory(prefix="bench_compositing_render_") as tmp:
        for label, repo in (("baseline", baseline_repo), ("today", REPO)):
            for rep in range(2):  # the first run fills the checkout's numba cache: not kept
                out = Path(tmp) / f"{label}_{rep}"
                a = list(args)
                a[a.index("--out") + 1] = str(out)
                with harness.clock() as t:
                    subprocess.run([sys.executable, "-m", "gs2e", *a], check=True,
                                   env=harness.gs2e_env(repo), capture_output=True, cwd=repo)
                cpu, wall = t.child_cpu_s, t.wall_s
            import pandas as pd

            fr = pd.read_parquet(out / "frames.parquet")
            blur[label] = [read_image(out / "blur" / f) for f in fr["file"]]
            rows.append({"scene": scene, "trajectory": traj, "code": label, "fps": fps,
                         "frames": len(fr), "subframes": int(fr["n_subframes"].sum()),
                         "cpu_s": cpu, "wall_s": wall, "cpu_s_per_frame": cpu / len(fr)})
            print(f"  {scene} render {label}: {len(fr)} frames, {rows[-1]['subframes']} sub-frames, "
                  f"{cpu:.1f} CPU-s ({rows[-1]['cpu_s_per_frame']:.2f} per frame)", flush=True)
    d = [np.abs(a.astype(np.int16) - b.astype(np.int16)) for a, b in zip(blur["today"], blur["baseline"])]
    for row in rows:
        row.update(blur_u8_max_diff=int(max(x.max() for x in d)),
                   blur_u8_frac_differ=float(np.mean([(x > 0).mean() for x in d])))
    return rows


def plot(kn, ev):
    """The kernels' ms per call, and the events' count against their CPU; the figure."""
    plt = harness.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    if kn is not None and len(kn):
        ax = axes[0]
        m = kn.groupby(["scene", "pass", "kernel"], sort=False)["ms"].median().unstack("kernel")
        labels = [f"{s}\n{p}" for s, p in m.index]
        x = np.arange(len(m))
        for i, k in enumerate(m.columns):
            ax.bar(x + (i - 1) * 0.27, m[k], 0.27, label=k)
        ax.set_xticks(x, labels, fontsize=6)
        ax.set_yscale("log")
        ax.set_ylabel("ms per call (median, 2 threads)")
        ax.set_title("compositing kernels on trained models")
        ax.legend(fontsize=7)
    if ev is not None and len(ev):
        ax = axes[1]
        for scene, g in ev.groupby("scene", sort=False):
            for code, h in g.groupby("code", sort=False):
                ax.plot(h["cpu_s_per_s"], h["n_events"] / 1e6, "o" if code == "today" else "s",
                        label=f"{scene} {code}")
        ax.set_xlabel("CPU-s per simulated s")
        ax.set_ylabel("events (millions), seeds 0 and 1")
        ax.set_title("gs2e events, fixed 2400 fps")
        ax.legend(fontsize=7)
    return fig


def report(kn, ev, name: str, sensor: str, rev: str, rn=None, files: list[Path] = ()) -> None:
    """Draw the plot (benchmarks/results/<name>.png), print the tables, the
    files and the headline."""
    files = [*files, harness.save_plot(plot(kn, ev), name)]
    print()
    head = []
    if kn is not None:
        m = kn.groupby(["scene", "pass", "kernel"], sort=False)["ms"].median().unstack("kernel")
        print(f"ms per call, median over poses (baseline: {rev}):")
        print(m.to_string(float_format=lambda x: f"{x:.1f}"))
        fw = kn[(kn["pass"] == "render forward") & (kn["kernel"] == "float32")]
        print(f"float32 render against the baseline's: worst {fw['psnr_db'].min():.1f} dB, largest "
              f"|d| {fw['max_abs'].max():.2e}, 8-bit values differing {fw['frac_u8_differ'].max():.2e}")
        tr = kn[kn["pass"] != "render forward"]
        if len(tr):
            t64, t32 = tr[tr["kernel"] == "float64"], tr[tr["kernel"] == "float32"]
            print(f"training passes, float64, same bits as the baseline: "
                  f"{bool(t64['same_bits_as_baseline'].all())}")
            if len(t32):
                print(f"training passes, float32 (splat.compute_dtype): gradients' q99 |diff| "
                      f"{t32['grad_q99_rel'].max():.1e} of each column's largest (median over columns)")
        for scene in m.index.get_level_values(0).unique():
            r = m.loc[(scene, "render forward")]
            head.append(f"{scene} render {r['baseline'] / r['float32']:.2f}x (float32), "
                        f"{r['baseline'] / r['float64']:.2f}x (float64)")
            if (scene, "train backward") in m.index and "float32" in m.columns:
                f, b = m.loc[(scene, "train forward")], m.loc[(scene, "train backward")]
                head.append(f"{scene} training passes {(f['baseline'] + b['baseline']) / (f['float32'] + b['float32']):.2f}x "
                            f"(float32), {(f['baseline'] + b['baseline']) / (f['float64'] + b['float64']):.2f}x (float64)")
            if "baseline_f32" in m.columns:  # today's float32 kernels against the baseline's
                f32 = [f"render {r['baseline_f32'] / r['float32']:.2f}x"]
                if (scene, "train backward") in m.index:
                    f, b = m.loc[(scene, "train forward")], m.loc[(scene, "train backward")]
                    f32.append(f"training forward {f['baseline_f32'] / f['float32']:.2f}x, "
                               f"backward {b['baseline_f32'] / b['float32']:.2f}x")
                head.append(f"{scene} float32 kernels against the baseline's: " + ", ".join(f32))
    if ev is not None:
        print("gs2e events, fixed 2400 fps (mean of seeds 0 and 1):")
        for scene, g in ev.groupby("scene", sort=False):
            b, t = g[g["code"] == "baseline"], g[g["code"] == "today"]
            ratio = b["cpu_s_per_s"].mean() / t["cpu_s_per_s"].mean()
            print(f"  {scene}: {b['cpu_s_per_s'].mean():.0f} -> {t['cpu_s_per_s'].mean():.0f} CPU-s per "
                  f"simulated s ({ratio:.2f}x); events {t['n_events'].mean() / b['n_events'].mean() - 1:+.3%} "
                  f"(seeds differ by {abs(t['n_events'].iloc[0] - t['n_events'].iloc[1]) / t['n_events'].mean():.3%}); "
                  f"per-pixel count distance today vs baseline at the same seed "
                  f"{t['count_dist_same_seed_other_code'].mean():.4f}, between seeds {t['count_dist_seeds'].iloc[0]:.4f}")
            head.append(f"{scene} events {ratio:.2f}x less CPU")
    if rn is not None:
        print("gs2e render (blurred frames):")
        for scene, g in rn.groupby("scene", sort=False):
            b, t = g[g["code"] == "baseline"].iloc[0], g[g["code"] == "today"].iloc[0]
            ratio = b["cpu_s_per_frame"] / t["cpu_s_per_frame"]
            print(f"  {scene}: {b['cpu_s_per_frame']:.2f} -> {t['cpu_s_per_frame']:.2f} CPU-s per frame "
                  f"({ratio:.2f}x; sub-frames {b['subframes']} -> {t['subframes']}); blurred 8-bit values "
                  f"differing {t['blur_u8_frac_differ']:.2e}, by at most {t['blur_u8_max_diff']}")
            head.append(f"{scene} render {ratio:.2f}x less CPU")
    harness.report(None, f"compositing at {sensor}, today against {rev}: " + "; ".join(head), files)


def main() -> None:
    ap = harness.parser(__doc__, quick="2 poses, 2 reps, 20 ms of events (minutes: still needs "
                                       "--sensor, --scenes and the cost run's models)",
                        baseline_rev=BASELINE_REV)
    ap.add_argument("--sensor", default="davis346", help="the cost run to use (cost_<sensor>; default davis346)")
    ap.add_argument("--scenes", help="comma-separated scenes of that run (default: every scene it trained)")
    ap.add_argument("--parts", default="kernel,events")
    ap.add_argument("--trajectory", default="mini00_medium")
    ap.add_argument("--poses", type=int, default=6)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--span-s", type=float, default=0.1, help="simulated span per events run (s)")
    ap.add_argument("--render-fps", type=float, default=3.0,
                    help="frames per second of the render part (the exposure stays the job's)")
    ap.add_argument("--report", action="store_true", help="only reprint and redraw from the CSVs")
    args = ap.parse_args()
    import pandas as pd

    name = f"bench_compositing_{args.sensor}"
    stem = harness.RESULTS / name
    if args.report:
        kn = pd.read_csv(f"{stem}_kernel.csv") if Path(f"{stem}_kernel.csv").exists() else None
        ev = pd.read_csv(f"{stem}_events.csv") if Path(f"{stem}_events.csv").exists() else None
        rn = pd.read_csv(f"{stem}_render.csv") if Path(f"{stem}_render.csv").exists() else None
        files = [f for p in ("kernel", "events", "render") if (f := Path(f"{stem}_{p}.csv")).exists()]
        return report(kn, ev, name, args.sensor, args.baseline_rev, rn, files)
    if not scenes_of_cost_run(ap, args, "compositing"):
        return
    if args.quick:
        args.poses, args.reps, args.span_s = 2, 2, 0.02
    results, cfg = cost_run(args.sensor)
    parts = set(args.parts.split(","))
    kn_rows, ev_rows, rn_rows = [], [], []
    # the baseline's checkout (a git worktree, removed afterwards) runs its whole commands
    with tempfile.TemporaryDirectory(prefix="bench_compositing_base_") as tmp, \
            (harness.baseline_checkout(args.baseline_rev) if parts & {"events", "render"}
             else nullcontext()) as checkout:
        tmp = Path(tmp)
        base = baseline_module(args.baseline_rev, tmp) if "kernel" in parts else None
        for scene in args.scenes.split(","):
            if "kernel" in parts:
                kn_rows += bench_kernel(results, cfg["events"], scene, args.trajectory, args.poses,
                                        args.reps, base, tmp)
            if "events" in parts:
                ev_rows += bench_events(results, cfg["events"], scene, args.trajectory, args.span_s,
                                        checkout)
                harness.write_csv(f"{name}_events", pd.DataFrame(ev_rows))  # kept if a later part fails
            if "render" in parts:
                rn_rows += bench_render(results, scene, args.trajectory, args.render_fps, checkout)
    files = []
    for part, rows in (("kernel", kn_rows), ("events", ev_rows), ("render", rn_rows)):
        if rows:
            files.append(harness.write_csv(f"{name}_{part}", pd.DataFrame(rows)))
    kn, ev, rn = (pd.DataFrame(r) if r else None for r in (kn_rows, ev_rows, rn_rows))
    report(kn, ev, name, args.sensor, args.baseline_rev, rn, files)


if __name__ == "__main__":
    main()
