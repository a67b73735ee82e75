"""Benchmark: event fidelity against a dense reference, per sampling method (issue 45).

For each scene x speed x sensor, one span of the ``base_<speed>`` trajectory
in full motion (from its middle) is simulated by every sampling method and by
a **dense reference**: whole renders at most 0.05 px of image motion apart
(``motion`` clock at 0.05 px, steps down to 1 us), whatever rate that takes.
The span is as long as the reference can afford (``--ref-renders`` renders,
at most ``--max-span-ms``), so the fast cases get short spans: each row says
its span.

Methods: ``fixed`` at 2400 fps (the paper, today's default; the baseline) and
1200 fps; the ``motion`` clock at 0.1, 0.25, 0.5 and 1 px between samples;
``tile`` (per-tile clocks at the contrast bound; DAVIS346 only, its samples
depend on the model it feeds, so it runs once per model).

Measured, per method, against the reference:

* ideal model (theta = 0.2, no noise: deterministic, compared one to one):
  event-count error |N - N_ref| / N_ref; per-pixel count L1 (sum over pixels
  and polarities of |n - n_ref|, over N_ref); timestamp error of events
  matched in order per pixel and polarity (p50, p99, us); ON fraction; the
  share of events whose time is a sample time (events "batched" on samples);
* DVS-Voltmeter (the sensor's preset, seed 0): count error and per-pixel L1
  against the reference at seed 0, and the same statistics of the reference
  at seed 1 against seed 0 (the spread of two seeds: what noise alone gives);
  ON fraction;
* CPU seconds per simulated second (process time of the whole run: rendering,
  sampling and both models, 2 threads) and renders.

``--window smooth`` (issue 67): the models trained with the smooth window
by ``bench_window.py`` (cached there), rendered continuous in time, each
against its own dense reference; their rows' methods are named ``smooth:
...``, so that ``--report cut.csv,smooth.csv`` compares them with the cut
window's ``fixed 2400`` case by case. Methods ``... cubic k`` feed k points
per step on the cubic through the renders (``events.sampling.substeps``);
``fixed F slopes k`` do so with each render's own slope
(``events.sampling.slopes: difference``: a second render 2 us later),
``fixed F tangent k`` with the tangent pass's exact slope (``slopes: tangent``);
``curve e cubic k`` set each step from the cubic's measured error, at most
e x theta (``events.sampling.mode: curve``, ``error_fraction``).

Scenes: ``demo``, ``temple_ring``, ``llff_fern`` and ``mouse_colmap`` as built
(cached) by bench_event_sampling.py (``event_runs.build_scenes``). ``--quick``: the tests' textured plane
(64 x 48, a fast pan), 5 ms, davis-free (the plane's own camera).

Usage: python benchmarks/bench_event_fidelity.py [--quick] [--scenes demo,temple_ring]
       [--sensors davis346,imx636] [--speeds mild,medium,strong] [--ref-renders 500] [--tag T]
       python benchmarks/bench_event_fidelity.py --report a.csv,b.csv
Writes benchmarks/results/bench_event_fidelity[_quick][_T].csv and .png; the last
line printed is the headline.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

import harness
from event_runs import (build_scenes, count_error, events_cfg, matched_dt_us, motion_rate_px_per_us,
                        plane_scene, reference_run, reference_span, run)

BASELINE = "fixed 2400"
METHODS = {  # name -> (mode, fps, sampling overrides)
    "fixed 2400": ("fixed", 2400.0, {}),
    "fixed 1200": ("fixed", 1200.0, {}),
    "motion 0.1": ("motion", 2400.0, {"max_motion_px": 0.1}),
    "motion 0.25": ("motion", 2400.0, {"max_motion_px": 0.25}),
    "motion 0.5": ("motion", 2400.0, {"max_motion_px": 0.5}),
    "motion 1": ("motion", 2400.0, {"max_motion_px": 1.0}),
    "tile": ("tile", 2400.0, {}),
    "motion 1 cubic 4": ("motion", 2400.0, {"max_motion_px": 1.0, "substeps": 4}),
    "motion 2 cubic 8": ("motion", 2400.0, {"max_motion_px": 2.0, "substeps": 8}),
    # a render and its 2 us difference per step, points on the Hermite curve with those slopes
    "fixed 1200 slopes 2": ("fixed", 1200.0, {"substeps": 2, "slopes": "difference"}),
    "fixed 600 slopes 4": ("fixed", 600.0, {"substeps": 4, "slopes": "difference"}),
    # the same with each render's slope from the tangent pass (no second render)
    "fixed 600 tangent 4": ("fixed", 600.0, {"substeps": 4, "slopes": "tangent"}),
    # the curve clock: steps from the cubic's measured error (a fraction of theta), 4 points per step
    "curve 0.02 cubic 4": ("curve", 2400.0, {"error_fraction": 0.02, "substeps": 4}),
    "curve 0.05 cubic 4": ("curve", 2400.0, {"error_fraction": 0.05, "substeps": 4}),
    "curve 0.1 cubic 4": ("curve", 2400.0, {"error_fraction": 0.1, "substeps": 4}),
    "curve 0.02 cubic 2": ("curve", 2400.0, {"error_fraction": 0.02, "substeps": 2}),
    "curve 0.02 cubic 8": ("curve", 2400.0, {"error_fraction": 0.02, "substeps": 8}),
    # ... with the worst 1 % of pixels set aside instead of 0.1 %
    "curve 0.05 cubic 4 outliers 0.01": ("curve", 2400.0, {"error_fraction": 0.05, "substeps": 4,
                                                           "outlier_fraction": 0.01}),
    "curve 0.1 cubic 4 outliers 0.01": ("curve", 2400.0, {"error_fraction": 0.1, "substeps": 4,
                                                          "outlier_fraction": 0.01}),
}
DEFAULT_METHODS = ("fixed 2400", "fixed 1200", "motion 0.1", "motion 0.25", "motion 0.5", "motion 1", "tile")


def ideal_metrics(ev, ref, shape, times_us) -> dict:
    dt = matched_dt_us(ev, ref, shape)
    n, n_ref = len(ev), len(ref)
    return {"n_ideal": n, "count_err": abs(n - n_ref) / max(1, n_ref),
            "l1": count_error(ev, ref, shape),
            "dt_p50_us": float(np.percentile(dt, 50)) if len(dt) else np.nan,
            "dt_p99_us": float(np.percentile(dt, 99)) if len(dt) else np.nan,
            "on_frac": float(ev.p.mean()) if n else np.nan,
            "on_sample_share": float(np.isin(ev.t, times_us).mean()) if n else np.nan}


def voltmeter_metrics(ev, ref0, ref1, shape) -> dict:
    n0 = max(1, len(ref0))
    return {"vm_n": len(ev), "vm_count_err": abs(len(ev) - len(ref0)) / n0,
            "vm_count_spread": abs(len(ref1) - len(ref0)) / n0,
            "vm_l1": count_error(ev, ref0, shape), "vm_l1_spread": count_error(ref1, ref0, shape),
            "vm_on_frac": float(ev.p.mean()) if len(ev) else np.nan}


def case(model_dir, traj, sensor_name: str | None, methods: list[str], ref_renders: int,
         max_span_us: int, prefix: str = "") -> list[dict]:
    """All methods and the reference on one scene x speed x sensor."""
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings

    sensor = {"sensor": sensor_name} if sensor_name else {}
    probe = RenderedSource(model_dir, traj, event_settings(events_cfg("ideal", "fixed", extra=sensor)))
    span = reference_span(probe, ref_renders, max_span_us)
    rate = motion_rate_px_per_us(probe, span[0])
    ref = reference_run(model_dir, traj, span, sensor, seeds=(0, 1))
    shape = ref["shape"]
    base = {"span_ms": (span[1] - span[0]) / 1e3, "motion_px_per_ms": rate * 1e3,
            "ref_renders": ref["renders"], "ref_n_ideal": len(ref["events"]["ideal"]),
            "ref_cpu_s_per_s": ref["cpu_s"] / (ref["duration_us"] * 1e-6)}
    rows = []
    for name in methods:
        mode, fps, samp = METHODS[name]
        if mode == "tile":  # samples follow the model fed: one run per model
            a = run(model_dir, traj, span, mode, fps, sample_for=("ideal",),
                    extra={**sensor, "sampling": samp})
            b = run(model_dir, traj, span, mode, fps, sample_for=("voltmeter",),
                    extra={**sensor, "sampling": samp})
            res = {**a, "cpu_s": a["cpu_s"] + b["cpu_s"], "events": {**a["events"], **b["events"]}}
        else:
            res = run(model_dir, traj, span, mode, fps, extra={**sensor, "sampling": samp})
        ev = res["events"]
        rows.append({"method": prefix + name, **base, "renders": res["renders"],
                     "cpu_s_per_s": res["cpu_s"] / (res["duration_us"] * 1e-6),
                     **ideal_metrics(ev["ideal"], ref["events"]["ideal"], shape, res["times_us"]),
                     **voltmeter_metrics(ev["voltmeter0"], ref["events"]["voltmeter0"],
                                         ref["events"]["voltmeter1"], shape)})
    return rows


def baseline(df) -> str:
    """The baseline method's name in ``df``: :data:`BASELINE`, or in a run of
    one window alone (``--window smooth``) that window's ``fixed 2400``."""
    if (df.method == BASELINE).any():
        return BASELINE
    return next(m for m in dict.fromkeys(df.method) if m.endswith(BASELINE))


def summarise(df):
    """Per method over all cases: CPU against the baseline and how often each
    error is no worse than the baseline's."""
    import pandas as pd

    key = ["scene", "speed", "sensor"]
    b = df[df.method == baseline(df)].set_index(key)
    out = []
    for name, g in df.groupby("method", sort=False):
        g = g.set_index(key)
        bb = b.loc[g.index]
        within = (g.vm_count_err <= g.vm_count_spread) & (g.vm_l1 <= 1.02 * g.vm_l1_spread)
        out.append({"method": name, "cases": len(g),
                    "cpu_ratio_median": float((g.cpu_s_per_s / bb.cpu_s_per_s).median()),
                    "cpu_ratio_max": float((g.cpu_s_per_s / bb.cpu_s_per_s).max()),
                    "count_err_median": float(g.count_err.median()),
                    "l1_median": float(g.l1.median()), "dt_p50_median_us": float(g.dt_p50_us.median()),
                    "no_worse_count": int((g.count_err <= bb.count_err + 1e-12).sum()),
                    "no_worse_l1": int((g.l1 <= bb.l1 + 1e-12).sum()),
                    "no_worse_dt_p50": int((g.dt_p50_us <= bb.dt_p50_us + 1e-9).sum()),
                    "vm_within_spread": int(within.sum())})
    return pd.DataFrame(out)


def summary(df) -> tuple[str, str]:
    """The table of every case and the per-method summary; the headline."""
    import pandas as pd

    with pd.option_context("display.width", 200, "display.max_columns", 30):
        cols = ["scene", "speed", "sensor", "method", "span_ms", "renders", "cpu_s_per_s",
                "count_err", "l1", "dt_p50_us", "dt_p99_us", "on_frac", "on_sample_share",
                "vm_count_err", "vm_count_spread", "vm_l1", "vm_l1_spread"]
        s = summarise(df)
        table = "\n".join([df[cols].to_string(index=False, float_format=lambda x: f"{x:.4g}"), "",
                           s.to_string(index=False, float_format=lambda x: f"{x:.3g}")])
    # the target: no worse than the baseline on every case at <= 1/3 its CPU
    n = int(s.cases.max())
    base_name = baseline(df)
    met = [r.method for r in s.itertuples() if r.method != base_name and r.cases == n
           and min(r.no_worse_count, r.no_worse_l1, r.no_worse_dt_p50) == n
           and r.cpu_ratio_max <= 1 / 3]
    b = df[df.method == base_name]
    spans = "; ".join(
        f"{m}: L1 {g.l1.min():.3f}-{g.l1.max():.3f} at {r.cpu_ratio_median:.2f}x (median) its CPU"
        for m, g in df.groupby("method", sort=False) if "motion" in m or "cubic" in m
        for r in s[s.method == m].itertuples())
    return table, (f"HEADLINE: {n} cases; {base_name} per-pixel L1 {b.l1.min():.3f}-{b.l1.max():.3f}; "
                   f"{spans}; " + (f"no worse everywhere at <= 1/3 the CPU: {', '.join(met)}" if met else
                                   "no method is no worse everywhere at <= 1/3 the CPU"))


def plot(df):
    """Per sensor: ideal per-pixel L1 against CPU relative to the baseline on
    the same case (one point per scene x speed); the figure."""
    plt = harness.pyplot()
    key = ["scene", "speed", "sensor"]
    base = df[df.method == baseline(df)].set_index(key).cpu_s_per_s
    rel = df.cpu_s_per_s.to_numpy() / base.loc[list(df[key].itertuples(index=False))].to_numpy()
    sensors = list(dict.fromkeys(df.sensor))
    fig, axes = plt.subplots(1, len(sensors), figsize=(6.5 * len(sensors), 4.8), squeeze=False)
    for ax, sensor in zip(axes[0], sensors):
        for name in dict.fromkeys(df.method):
            m = ((df.sensor == sensor) & (df.method == name)).to_numpy()
            ax.scatter(rel[m], np.maximum(df.l1.to_numpy()[m], 1e-4), label=name, s=18)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axvline(1 / 3, color="grey", lw=0.8, ls="--")
        ax.set_xlabel(f"CPU relative to {baseline(df)} on the same case")
        ax.set_ylabel("ideal per-pixel count L1 vs dense reference")
        ax.set_title(f"{sensor}: one point per scene x speed")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    return fig


def main() -> None:
    ap = harness.parser(__doc__, quick="test plane, 5 ms (about a minute)")
    ap.add_argument("--scenes", default="demo,temple_ring,llff_fern,mouse_colmap")
    ap.add_argument("--speeds", default="mild,medium,strong")
    ap.add_argument("--sensors", default="davis346,imx636")
    ap.add_argument("--methods", default=",".join(DEFAULT_METHODS),
                    help=f"of {', '.join(METHODS)} ({BASELINE}, the baseline, always runs)")
    ap.add_argument("--window", choices=["cut", "smooth"], default="cut",
                    help="the models' compositing window (smooth: bench_window.py's models)")
    ap.add_argument("--ref-renders", type=int, default=500,
                    help="renders the reference may take per case (sets the span)")
    ap.add_argument("--hd-ref-renders", type=int, default=150, help="the same at imx636")
    ap.add_argument("--max-span-ms", type=float, default=100.0)
    ap.add_argument("--tag", default="", help="appended to the CSV/plot name (runs in parts)")
    ap.add_argument("--report", metavar="CSV[,CSV]",
                    help="only reprint and redraw from CSVs (concatenated; the plot beside the first)")
    args = ap.parse_args()
    import pandas as pd

    name = ("bench_event_fidelity" + ("_quick" if args.quick else "") + (f"_{args.tag}" if args.tag else "")
            + ("_smooth" if args.window == "smooth" else ""))
    if args.report:
        paths = args.report.split(",")
        df = pd.concat([pd.read_csv(p) for p in paths], ignore_index=True)
        first = Path(paths[0]).resolve()
        # an absolute name: the plot goes beside the first CSV
        png = harness.save_plot(plot(df), str(first.with_name(first.stem + "_all")), dpi=110)
        harness.report(*summary(df), [png])
        return
    with harness.clock() as total:
        df = measure(args)
    csv = harness.write_csv(name, df.to_dict("records"))
    png = harness.save_plot(plot(df), name, dpi=110)
    print(f"{len(df)} rows in {total.wall_s:.0f} s")
    harness.report(*summary(df), [csv, png])


def measure(args):
    """Every case's rows (one per method) as a table."""
    import pandas as pd

    methods = args.methods.split(",")
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"--methods: unknown {unknown} (of {', '.join(METHODS)})")
    if BASELINE not in methods:  # every case is compared with it: it always runs
        methods.insert(0, BASELINE)
    rows = []
    if args.quick:
        tmp = Path(tempfile.mkdtemp(prefix="bench_ef_"))
        model, traj = plane_scene(tmp)
        for r in case(model, traj, None, [m for m in methods if m != "tile"], 200, 5000):
            rows.append({"scene": "plane", "speed": "fast", "sensor": "64x48", **r})
            print(rows[-1], flush=True)
    else:
        dirs = build_scenes(args.scenes.split(","))
        prefix = "smooth: " if args.window == "smooth" else ""
        for scene, d in dirs.items():
            model = d / "splat" if args.window == "cut" else harness.RESULTS / "bench_window_cache" / scene / "smooth"
            if not (model / "model.json").exists():
                raise SystemExit(f"{model} is missing: run benchmarks/bench_window.py first")
            for speed in args.speeds.split(","):
                for sensor in args.sensors.split(","):
                    hd = sensor != "davis346"
                    ms = [m for m in methods if not (hd and m == "tile")]
                    with harness.clock() as t:
                        for r in case(model, d / "trajectories" / f"base_{speed}.npz", sensor,
                                      ms, args.hd_ref_renders if hd else args.ref_renders,
                                      int(args.max_span_ms * 1e3), prefix):
                            rows.append({"scene": scene, "speed": speed, "sensor": sensor, **r})
                    print(f"{scene} {speed} {sensor}: span {rows[-1]['span_ms']:.2f} ms, "
                          f"{t.wall_s:.0f} s", flush=True)
    return pd.DataFrame(rows)


if __name__ == "__main__":
    main()
