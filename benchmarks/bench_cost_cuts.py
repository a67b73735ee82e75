"""Speed against error of cuts to the cost model's largest terms (issue 32).

Runs on the models that ``bench_cost_model.py --run SCENE --sensor S`` trained
(``benchmarks/results/cost_<sensor>/results/<scene>/``), at that run's settings
(``config/paper.yaml``'s trajectories and event settings, the sensor's camera):

* ``events``: the whole ``gs2e events`` command (a fresh process, CPU seconds of
  all its threads) on the first ``--span-s`` of a trajectory with the paper's
  fixed 2400 fps sampling and with per-tile sampling at each ``--tile-bounds``
  (events.sampling.bound_fraction), seeds 0 and 1 each, and with ``--ref-fps``
  a fixed-rate reference (one seed, e.g. 24000 fps). DVS-Voltmeter is
  stochastic: the yardsticks are the spread between the two fixed 2400 fps
  seeds, and the reference. Per run: event count, ON fraction, and the
  per-pixel count distance (sum over pixels and polarities of |n_a - n_b|, over
  the mean event count) to a run of the other seed (runs of one seed share
  their random draws).
* ``blur``: the blurred frame (the render stage's exposure, linear-light mean)
  of the ``--frames`` frames with the most motion, from n = 8 .. 128 midpoint
  sub-frames and by the render stage's adaptive rule
  (``render.blur_tolerance_db`` 50, 55, 60: :func:`gs2e.render.blur.adaptive_blur`),
  against 256 midpoint sub-frames: PSNR and largest difference of the 8-bit
  frames, sub-frames rendered and CPU seconds per frame.

Usage:
    python benchmarks/bench_cost_cuts.py --sensor imx636 --scenes mouse_colmap
    python benchmarks/bench_cost_cuts.py --sensor davis346 --scenes temple_ring,llff_fern
Writes benchmarks/results/bench_cost_cuts_<sensor>_{events,blur}.csv and
bench_cost_cuts_<sensor>.png; the last printed line is the headline.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

import harness
from event_runs import PAPER_FPS, cost_run, count_distance, pixel_counts, run_events, scenes_of_cost_run

BLUR_N = (8, 16, 32, 64, 128)
BLUR_REF_N = 256
BLUR_TOLERANCES_DB = (50.0, 55.0, 60.0)


# ------------------------------------------------------------------ events
def bench_events(results: Path, events_cfg: dict, scene: str, traj: str, span_s: float,
                 bounds: list[float], ref_fps: float | None) -> list[dict]:
    rows, counts = [], {}
    runs = [(("fixed", PAPER_FPS, None), seed) for seed in (0, 1)]
    runs += [(("tile", PAPER_FPS, b), seed) for b in bounds for seed in (0, 1)]
    if ref_fps:  # one seed: the others' seed-0 runs are compared with it
        runs.append((("fixed", ref_fps, None), 1))
    with tempfile.TemporaryDirectory(prefix="bench_cuts_") as tmp:
        for (mode, fps, bound), seed in runs:
            label = f"fixed {fps:g}" if mode == "fixed" else f"tile {bound:g}θ"
            r = run_events(results / scene, traj, events_cfg, mode, fps, bound or 1.0, seed, span_s,
                           Path(tmp) / f"{mode}{fps}{bound}_{seed}")
            st = r["stats"]
            counts[(label, seed)] = pixel_counts(r["events"], st["width"], st["height"])
            rows.append({"scene": scene, "trajectory": traj, "setting": label, "mode": mode,
                         "bound_fraction": bound, "seed": seed,
                         "width": st["width"], "height": st["height"], "span_s": st["duration_s"],
                         "n_events": st["n_events"], "on_fraction": st["on_fraction"],
                         "pixel_samples": st["pixel_samples"], "cpu_s": r["cpu_s"], "wall_s": r["wall_s"],
                         "cpu_s_per_s": r["cpu_s"] / st["duration_s"],
                         "simulate_s": st["simulate_s"], "source_s": st["source_s"], "model_s": st["model_s"]})
            print(f"  {scene} {traj} {label:9s} seed {seed}: {st['n_events']:>11,} events, "
                  f"ON {st['on_fraction']:.4f}, {r['cpu_s']:.1f} CPU-s ({rows[-1]['cpu_s_per_s']:.0f} per "
                  f"simulated s)", flush=True)
    paper = f"fixed {PAPER_FPS:g}"
    ref = f"fixed {ref_fps:g}" if ref_fps else None
    floor = count_distance(counts[(paper, 0)], counts[(paper, 1)])
    for row in rows:
        lb, sd = row["setting"], row["seed"]
        # against a run of the other seed: runs of one seed share their random draws
        row.update(count_dist_fixed_seeds=floor,
                   count_dist_vs_fixed=count_distance(counts[(lb, sd)], counts[(paper, 1 - sd)]),
                   count_dist_vs_ref=(count_distance(counts[(lb, sd)], counts[(ref, 1)])
                                      if ref and sd == 0 else None),
                   n_events_ref=int(counts[(ref, 1)].sum()) if ref else None)
    return rows


# ------------------------------------------------------------------ blur
def bench_blur(results: Path, cfg: dict, scene: str, traj: str, n_frames: int) -> list[dict]:
    import pandas as pd

    from gs2e.events.sensors import get_sensor
    from gs2e.events.settings import event_settings
    from gs2e.io.images import to_u8
    from gs2e.render.blur import adaptive_blur, average_srgb, subframe_times_us
    from gs2e.render.renderer import TrajectoryRenderer

    sensor = get_sensor(event_settings(cfg["events"]))
    sensor_arg = None if sensor is None else (tuple(sensor.size), cfg["events"]["sensor_fit"])
    r = TrajectoryRenderer(results / scene / "splat", results / scene / "trajectories" / f"{traj}.npz",
                           cfg["render"]["background"], cfg["render"]["scale"], "cpu", sensor=sensor_arg)
    frames = pd.read_parquet(results / scene / "frames" / traj / "frames.parquet")
    frames = frames.sort_values("motion_px_p99", ascending=False).head(n_frames)
    E = float(cfg["render"]["exposure_us"])
    rows = []

    def u8(x):  # the 8-bit values the render stage writes, as floats for differences
        return to_u8(x).astype(np.float64)

    for _, fr in frames.iterrows():
        t = float(fr["t_us"])
        blurred, cpu = {}, {}
        for n in (*BLUR_N, BLUR_REF_N):
            ts = np.clip(subframe_times_us(t, E, n), r.t0_us, r.t1_us)
            with harness.clock() as c:
                blurred[n] = u8(average_srgb([r.render_pose(r.pose(tk))[0] for tk in ts]))
            cpu[n] = c.cpu_s
        ref = blurred[BLUR_REF_N]
        renders = {n: n for n in BLUR_N}
        sharp = r.render_pose(r.pose(t))[0]
        for tol in BLUR_TOLERANCES_DB:  # the render stage's rule (render.blur_tolerance_db)
            with harness.clock() as c:
                img, used, slices = adaptive_blur(lambda tk: r.render_pose(r.pose(tk))[0], t, E,
                                                  (r.t0_us, r.t1_us), tol, 64, known={t: sharp})
            key = f"adaptive {tol:g} dB"
            blurred[key], cpu[key], renders[key] = u8(img), c.cpu_s, used
        for n in [*BLUR_N, *(k for k in blurred if isinstance(k, str))]:
            mse = float(np.mean(((blurred[n] - ref) / 255.0) ** 2))
            rows.append({"scene": scene, "trajectory": traj, "frame": int(fr["frame"]),
                         "width": r.width, "height": r.height,
                         "motion_px_p99": float(fr["motion_px_p99"]),
                         "rule": n if isinstance(n, str) else f"midpoint {n}", "n_subframes": renders[n],
                         "step_px": float(fr["motion_px_p99"]) / renders[n],
                         "psnr_vs_ref_db": float("inf") if mse == 0 else -10 * np.log10(mse),
                         "max_abs_diff_u8": float(np.abs(blurred[n] - ref).max()),
                         "frac_pixels_off_u8": float(np.mean(np.abs(blurred[n] - ref) > 0)),
                         "cpu_s": cpu[n], "ref_n": BLUR_REF_N})
            print(f"  {scene} {traj} frame {rows[-1]['frame']} (p99 motion {rows[-1]['motion_px_p99']:.0f} px)"
                  f" {rows[-1]['rule']} n={renders[n]:3d}: {rows[-1]['psnr_vs_ref_db']:.1f} dB vs n={BLUR_REF_N}, max |d| "
                  f"{rows[-1]['max_abs_diff_u8']:.0f}/255, {cpu[n]:.1f} CPU-s", flush=True)
    return rows


# ------------------------------------------------------------------ report
def plot(ev, bl):
    """The events' count against their CPU, and the blurred frames' PSNR
    against their sub-frames; the figure."""
    plt = harness.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    if ev is not None and len(ev):
        ax = axes[0]
        for scene, g in ev.groupby("scene", sort=False):
            base = (g["n_events_ref"].iloc[0] if g["n_events_ref"].notna().any()
                    else g.loc[g["setting"] == f"fixed {PAPER_FPS:g}", "n_events"].mean())
            m = g.groupby("setting", sort=False).agg(cpu=("cpu_s_per_s", "mean"), n=("n_events", "mean"))
            line, = ax.plot(m["cpu"], 100 * (m["n"] / base - 1), "o", label=scene)
            for name, r in m.iterrows():
                ax.annotate(name, (r["cpu"], 100 * (r["n"] / base - 1)), fontsize=6, color=line.get_color())
        ax.axhline(0, c="k", lw=0.6)
        ax.set_xscale("log")
        ax.set_xlabel("CPU-s per simulated s")
        ax.set_ylabel("DVS-Voltmeter events against the reference (%)")
        ax.set_title("event stage: sampling")
        ax.legend(fontsize=7)
    if bl is not None and len(bl):
        ax = axes[1]
        for (scene, frame), g in bl.groupby(["scene", "frame"]):
            mid = g[g["rule"].str.startswith("midpoint")]
            line, = ax.plot(mid["n_subframes"], mid["psnr_vs_ref_db"], "o-", label=f"{scene} f{frame} midpoint")
            ad = g[g["rule"] == "adaptive 55 dB"]
            ax.plot(ad["n_subframes"], ad["psnr_vs_ref_db"], "*", ms=11, c=line.get_color(),
                    label=f"{scene} f{frame} adaptive 55 dB")
        ax.axhline(-10 * np.log10(1 / 12 / 255 ** 2), ls=":", c="k", lw=0.8)
        ax.set_xscale("log", base=2)
        ax.set_xlabel("sub-frames rendered")
        ax.set_ylabel(f"PSNR vs {BLUR_REF_N} sub-frames (dB, 8-bit)\n(dotted: 8-bit rounding noise)")
        ax.set_title("blurred frames")
        ax.legend(fontsize=6)
    return fig


def main() -> None:
    ap = harness.parser(__doc__, quick="50 ms per events run, 1 blurred frame per scene (minutes: "
                                       "still needs --sensor, --scenes and the cost run's models)")
    ap.add_argument("--sensor", default="davis346", help="the cost run to use (cost_<sensor>; default davis346)")
    ap.add_argument("--scenes", help="comma-separated scenes of that run (default: every scene it trained)")
    ap.add_argument("--report", action="store_true", help="only reprint and redraw from the CSVs")
    ap.add_argument("--parts", default="events,blur")
    ap.add_argument("--trajectory", default="mini00_medium")
    ap.add_argument("--tile-bounds", default="1,0.5,0.25",
                    help="events.sampling.bound_fraction values of the tile runs")
    ap.add_argument("--ref-fps", type=float, default=None,
                    help="also a fixed-rate reference at this rate (one seed), e.g. 24000")
    ap.add_argument("--span-s", type=float, default=0.2, help="simulated span per events run (s)")
    ap.add_argument("--frames", type=int, default=2, help="blurred frames per scene (most motion)")
    args = ap.parse_args()
    import pandas as pd

    if args.quick:
        args.span_s, args.frames = 0.05, 1
    if not args.report and not scenes_of_cost_run(ap, args, "cost cuts"):
        return
    name = f"bench_cost_cuts_{args.sensor}"
    stem = harness.RESULTS / name
    if args.report:  # reprint and redraw from the CSVs of an earlier run
        ev = pd.read_csv(f"{stem}_events.csv") if Path(f"{stem}_events.csv").exists() else None
        bl = pd.read_csv(f"{stem}_blur.csv") if Path(f"{stem}_blur.csv").exists() else None
        files = [f for f in (Path(f"{stem}_events.csv"), Path(f"{stem}_blur.csv")) if f.exists()]
        return report(ev, bl, name, args.sensor, files)
    results, cfg = cost_run(args.sensor)
    parts = set(args.parts.split(","))
    ev_rows, bl_rows = [], []
    for scene in (args.scenes or "").split(","):
        if "events" in parts:
            ev_rows += bench_events(results, cfg["events"], scene, args.trajectory, args.span_s,
                                    [float(b) for b in args.tile_bounds.split(",")], args.ref_fps)
        if "blur" in parts:
            bl_rows += bench_blur(results, cfg, scene, args.trajectory, args.frames)
    ev = pd.DataFrame(ev_rows) if ev_rows else None
    bl = pd.DataFrame(bl_rows) if bl_rows else None
    files = []
    if ev is not None:
        files.append(harness.write_csv(f"{name}_events", ev))
    if bl is not None:
        files.append(harness.write_csv(f"{name}_blur", bl))
    report(ev, bl, name, args.sensor, files)


def report(ev, bl, name: str, sensor: str, files: list[Path]) -> None:
    """Draw the plot (benchmarks/results/<name>.png), print the tables, the
    files and the headline."""
    files = [*files, harness.save_plot(plot(ev, bl), name)]
    print()
    if bl is not None:
        t = bl.groupby("rule", sort=False).agg(
            sub_frames=("n_subframes", "mean"), psnr_min=("psnr_vs_ref_db", "min"),
            max_abs_u8=("max_abs_diff_u8", "max"), cpu_s=("cpu_s", "mean"))
        print(f"blurred frames against {BLUR_REF_N} sub-frames (worst frame):")
        print(t.to_string(float_format=lambda x: f"{x:.2f}"))
    if ev is not None:
        print("event stage: settings against the paper's fixed 2400 fps (mean of seeds 0 and 1):")
        for scene, g in ev.groupby("scene", sort=False):
            f = g[g["setting"] == f"fixed {PAPER_FPS:g}"]
            n_f, spread = f["n_events"].mean(), abs(f["n_events"].iloc[0] - f["n_events"].iloc[1]) / f["n_events"].mean()
            print(f"  {scene}: seeds of fixed 2400 fps differ by {spread:.2%} in count, "
                  f"{g['count_dist_fixed_seeds'].iloc[0]:.4f} in per-pixel count distance")
            for setting, h in g.groupby("setting", sort=False):
                print(f"    {setting:10s} {h['cpu_s_per_s'].mean():7.1f} CPU-s per simulated s "
                      f"({h['cpu_s_per_s'].mean() / f['cpu_s_per_s'].mean():.2f}x fixed 2400's), events "
                      f"{h['n_events'].mean() / n_f - 1:+.2%}, ON {h['on_fraction'].mean():.4f}, "
                      f"count distance {h['count_dist_vs_fixed'].mean():.4f}"
                      + ("" if h["n_events_ref"].isna().all() else
                         f"; against the {g['n_events_ref'].iloc[0]:,.0f} events of the reference: "
                         f"{h['n_events'].iloc[0] / g['n_events_ref'].iloc[0] - 1:+.2%}, count distance "
                         f"{h['count_dist_vs_ref'].iloc[0]:.4f}"))
    head = []
    if bl is not None:
        ad, mid = bl[bl["rule"] == "adaptive 55 dB"], bl[bl["rule"] == "midpoint 64"]
        head.append(f"blurred frames by the adaptive rule (55 dB): {ad['n_subframes'].mean():.0f} sub-frames, "
                    f"worst {ad['psnr_vs_ref_db'].min():.1f} dB against {BLUR_REF_N} "
                    f"(64 midpoint sub-frames: {mid['psnr_vs_ref_db'].min():.1f} dB, "
                    f"{mid['cpu_s'].mean() / ad['cpu_s'].mean():.2f}x the CPU)")
    if ev is not None and ev["n_events_ref"].notna().any():
        for scene, g in ev.groupby("scene", sort=False):
            ref = g["n_events_ref"].iloc[0]
            f = g[g["setting"] == f"fixed {PAPER_FPS:g}"]
            t1 = g[g["setting"] == "tile 1θ"]
            if len(t1):
                head.append(f"{scene} events against the reference: fixed 2400 fps "
                            f"{f['n_events'].mean() / ref - 1:+.2%}, tile 1θ {t1['n_events'].mean() / ref - 1:+.2%} "
                            f"at {t1['cpu_s_per_s'].mean() / f['cpu_s_per_s'].mean():.2f}x the CPU")
    harness.report(None, f"cuts at {sensor}: " + "; ".join(head), files)


if __name__ == "__main__":
    main()
