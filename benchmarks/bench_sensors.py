"""Benchmark: events for each target sensor (events.sensor) on a trained model (issue 13).

For each built-in sensor preset (and, as the baseline, no sensor: the
trajectory camera's own size), the whole ``gs2e events`` command runs as a
fresh process on the same span of the same trajectory (default: the demo's
trained model, ``base_medium``, 50 ms from its middle; DVS-Voltmeter dvs346,
tile sampling, the preset's noise). Measured per preset: wall seconds, events,
events per wall second, simulated seconds per wall second, rendered pixel
values, peak RSS of the process (wait4), and the event statistics beside a
real recording (rate per pixel, ON fraction, median per-pixel inter-event
interval): by default ../shared/data/events/dvxplorer_sample.aedat4, a
DVXplorer recording, which the ``dvxplorer`` row is the sim-to-real check for.

Model: ``--model`` / ``--trajectory``; default results/demo/{splat,
trajectories/base_medium.npz} (``make demo``), else the cache that
bench_event_sampling.py builds. ``--quick``: the tests' textured plane
(``event_runs.plane_scene``), 5 ms (under 60 s).

Usage: python benchmarks/bench_sensors.py [--quick] [--span-ms 50]
Writes benchmarks/results/bench_sensors[_quick].csv and .png; the last line
printed is the headline.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

import harness
from event_runs import CACHE, plane_scene
from harness import REPO

from gs2e.events.sensors import SENSORS

REAL = harness.SHARED / "events" / "dvxplorer_sample.aedat4"


def find_model(args) -> tuple[Path, Path]:
    if args.model:
        return Path(args.model), Path(args.trajectory)
    for root in (REPO / "results" / "demo", CACHE / "results" / "demo"):
        if (root / "splat").is_dir() and (root / "trajectories" / "base_medium.npz").is_file():
            return root / "splat", root / "trajectories" / "base_medium.npz"
    raise SystemExit("no trained demo model: run `make demo` or pass --model/--trajectory")


def cut_trajectory(traj: Path, span_us: tuple[int, int], out: Path) -> int:
    """The trajectory's samples around ``span_us`` as a trajectory of its own
    (the pose curve is kept whole, so poses are unchanged); returns its start."""
    from gs2e.trajectory import load_trajectory
    from gs2e.trajectory.io import save_trajectory
    from gs2e.trajectory.trajectory import Trajectory

    tr = load_trajectory(traj)
    i0 = max(0, int(np.searchsorted(tr.t_us, span_us[0], "right")) - 1)
    i1 = min(len(tr.t_us), int(np.searchsorted(tr.t_us, span_us[1], "left")) + 1)
    d = tr.to_arrays()
    for k in ("t_us", "s", "ds_dt", "c2w"):
        d[k] = d[k][i0:i1]
    save_trajectory(out, Trajectory.from_arrays(d))
    return int(tr.t_us[i0])


def run_events(model: Path, traj: Path, span_us: tuple[int, int], sensor: str | None,
               out: Path) -> dict:
    """One fresh ``gs2e events`` process; wall time and peak RSS (wait4)."""
    cfg = {"sensor": sensor, "preview": False}
    with tempfile.TemporaryDirectory() as d:
        # the span: a copy of the trajectory cut to it keeps the command the workflow's
        cut = Path(d) / "span.npz"
        t0 = cut_trajectory(traj, span_us, cut)
        cfg["max_duration_s"] = (span_us[1] - t0) * 1e-6
        r = harness.run_child([sys.executable, "-m", "gs2e", "events", "--model", str(model),
                               "--trajectory", str(cut), "-o", str(out), "--threads", "2",
                               "--config-json", json.dumps(cfg)], env=harness.gs2e_env(REPO))
        if r.returncode != 0:
            raise SystemExit(f"gs2e events failed for sensor {sensor}: {r.output.strip()[-500:]}")
    st = json.loads((out / "stats.json").read_text())["stats"]
    return {"wall_s": r.wall_s, "peak_rss_mb": r.peak_rss_mb, **st}


def main() -> None:
    ap = harness.parser(__doc__, quick="test plane, 5 ms (under 60 s)")
    ap.add_argument("--model")
    ap.add_argument("--trajectory")
    ap.add_argument("--span-ms", type=float, default=50.0)
    ap.add_argument("--real", default=str(REAL), help="real recording for the sim-to-real columns")
    args = ap.parse_args()
    with harness.clock() as total:
        rows, traj, span_ms = measure(args)
    stem = "bench_sensors" + ("_quick" if args.quick else "")
    csv = harness.write_csv(stem, rows)
    png = harness.save_plot(plot(rows), stem, dpi=110)
    import pandas as pd

    big = rows[len(SENSORS)]  # imx636, the largest array
    base = rows[0]
    print(f"measured in {total.wall_s:.0f} s")
    harness.report(
        "\n" + pd.DataFrame(rows).to_string(index=False, float_format="%.4g"),
        f"HEADLINE: {span_ms:g} ms of {traj.stem}: imx636 (1280x720) "
        f"{big['events_per_wall_s'] / 1e6:.2f} M events/s wall, {big['simulate_s_per_s']:.0f} s per "
        f"simulated s, peak RSS {big['peak_rss_mb']:.0f} MB; the trajectory camera "
        f"({base['width']}x{base['height']}) {base['events_per_wall_s'] / 1e6:.2f} M events/s, "
        f"{base['simulate_s_per_s']:.0f} s per simulated s, {base['peak_rss_mb']:.0f} MB", [csv, png])


def measure(args) -> tuple[list[dict], Path, float]:
    """One row per sensor (and the real recording); the trajectory and the
    span (ms) simulated."""
    from gs2e.trajectory import load_trajectory

    tmp = Path(tempfile.mkdtemp(prefix="bench_sensors_"))
    if args.quick:
        model, traj = plane_scene(tmp)
        span_ms = 5.0
    else:
        model, traj = find_model(args)
        span_ms = args.span_ms
    tr = load_trajectory(traj)
    mid = int((tr.t_us[0] + tr.t_us[-1]) // 2)
    span = (mid, mid + int(span_ms * 1000))
    rows = []
    real = None
    if Path(args.real).is_file():
        from gs2e.events.io import read_events
        from gs2e.events.stats import event_stats

        ev, shape = read_events(args.real)
        real = event_stats(ev, shape, name=Path(args.real).name)
    run_events(model, traj, span, None, tmp / "warm")  # numba's cache filled outside the timings
    for sensor in [None, *SENSORS]:
        r = run_events(model, traj, span, sensor, tmp / f"ev_{sensor}")
        row = {"sensor": sensor or "none (trajectory camera)",
               "width": r["width"] if "width" in r else None, "height": r.get("height"),
               "wall_s": r["wall_s"], "simulated_s": r["duration_s"], "n_events": r["n_events"],
               "events_per_wall_s": r["n_events"] / r["wall_s"],
               "simulate_s_per_s": r["simulate_s_per_s"], "pixel_samples": r["pixel_samples"],
               "peak_rss_mb": r["peak_rss_mb"], "rate_hz_per_px": r.get("density_mean_hz"),
               "on_fraction": r.get("on_fraction"), "iei_median_ms": r.get("iei_median_ms")}
        rows.append(row)
        print(f"{row['sensor']:26s} {r['n_events']:9d} events in {r['wall_s']:6.1f} s wall "
              f"({row['events_per_wall_s'] / 1e6:.2f} M ev/s; simulation {r['simulate_s']:.1f} s = "
              f"{r['simulate_s_per_s']:.0f} s per simulated s), peak RSS {r['peak_rss_mb']:.0f} MB",
              flush=True)
    if real is not None:
        rows.append({"sensor": f"real: {Path(args.real).name}", "width": None, "height": None,
                     "wall_s": None, "simulated_s": real.get("duration_s"),
                     "n_events": real["n_events"], "events_per_wall_s": None,
                     "simulate_s_per_s": None, "pixel_samples": None, "peak_rss_mb": None,
                     "rate_hz_per_px": real.get("density_mean_hz"),
                     "on_fraction": real.get("on_fraction"),
                     "iei_median_ms": real.get("iei_median_ms")})
    return rows, traj, span_ms


def plot(rows: list[dict]):
    """Per sensor: wall s per simulated s, peak RSS and event rate (beside the
    real recording's); the figure."""
    plt = harness.pyplot()
    sim = [r for r in rows if r["wall_s"] is not None]
    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    names = [r["sensor"].split(" ")[0] for r in sim]
    axes[0].bar(names, [r["simulate_s_per_s"] for r in sim])
    axes[0].set_ylabel("wall s per simulated s")
    axes[1].bar(names, [r["peak_rss_mb"] for r in sim])
    axes[1].set_ylabel("peak RSS (MB)")
    every = [r for r in rows if r["rate_hz_per_px"] is not None]
    axes[2].bar([r["sensor"].split(" ")[0][:14] for r in every],
                [r["rate_hz_per_px"] for r in every],
                color=["tab:orange" if r["sensor"].startswith("real") else "tab:blue" for r in every])
    axes[2].set_ylabel("events per pixel per second")
    axes[2].set_yscale("log")
    for ax in axes:
        ax.tick_params(axis="x", rotation=30, labelsize=8)
        ax.grid(True, axis="y", alpha=0.3)
    return fig


if __name__ == "__main__":
    main()
