"""Benchmark: the event stage's samples rendered by gsplat (CUDA) against the CPU renderer.

Needs a CUDA GPU and gsplat (``pip install -e .[cuda]``). On the trained demo
(DAVIS346) and mouse_colmap (IMX636) models cached by bench_event_sampling.py
(``benchmarks/results/bench_event_sampling_cache``; pass ``--cache`` for
another copy), a span from the middle of ``base_mild`` and ``base_strong`` is
simulated with the ideal model (theta = 0.2) by ``fixed`` 2400 fps and the
``motion`` clock at 0.5 px, once per backend. Measured: renders, wall and
process-CPU seconds per simulated second, events, and the per-pixel count L1
between the backends' events (gsplat computes in float32 with its own alpha
clamp: not the same events). The first gsplat call builds its CUDA code and is
not timed; numba's kernels are compiled by an untimed CPU call first.

Without CUDA or gsplat it says why and exits 0. ``--quick``: demo only, 10 ms.

Usage: python benchmarks/bench_events_gpu.py [--quick] [--cache DIR] [--threads N]
Writes benchmarks/results/bench_events_gpu.csv and .png; the last line printed
is the headline.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import harness
from event_runs import CACHE, pixel_counts

CASES = (("demo", "davis346", 40.0), ("mouse_colmap", "imx636", 10.0))  # scene, sensor, span ms
METHODS = (("fixed", None), ("motion", 0.5))


def events_cfg(mode: str, sensor: str, motion_px: float | None) -> dict:
    """The ideal model (theta = 0.2) at ``sensor``, sampled by ``mode`` (the
    motion clock at ``motion_px`` px between samples)."""
    from gs2e.config import load_config

    samp = {"mode": mode, "fixed_fps": 2400.0}
    if motion_px is not None:
        samp["max_motion_px"] = motion_px
    return load_config({"events": {"model": "ideal", "sensor": sensor, "theta_on": 0.2,
                                   "theta_off": 0.2, "sampling": samp}})["events"]


def simulate(scene_dir: Path, speed: str, sensor: str, mode: str, motion_px, backend: str,
             span_ms: float) -> tuple[dict, np.ndarray]:
    """Ideal events over ``span_ms`` from the middle of base_<speed>; the row and
    the per-pixel x polarity counts."""
    from gs2e.events.models import Events, make_model
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings

    traj = scene_dir / "trajectories" / f"base_{speed}.npz"
    cfg = events_cfg(mode, sensor, motion_px)
    probe = RenderedSource(scene_dir / "splat", traj, event_settings(cfg))
    t0 = (probe.t0_us + probe.t1_us) // 2
    span = (t0, min(probe.t1_us, t0 + int(span_ms * 1e3)))
    src = RenderedSource(scene_dir / "splat", traj, event_settings(cfg), backend=backend, span_us=span,
                         batch_frames=64)
    with harness.clock() as t:
        t_start, f0 = src.start()
        model = make_model(event_settings(cfg), src.shape, 0)[0]
        model.start(t_start, f0)
        ev = Events.concat([model.process_batch(*b) for b in src.batches()] + [model.flush()])
    wall, cpu = t.wall_s, t.cpu_s
    sim_s = (span[1] - span[0]) * 1e-6
    H, W = src.shape
    counts = pixel_counts(ev, W, H)
    return {"scene": scene_dir.name, "speed": speed, "sensor": sensor,
            "method": mode if motion_px is None else f"{mode} {motion_px:g}", "backend": backend,
            "span_ms": sim_s * 1e3, "renders": src.stats.renders, "wall_s_per_s": wall / sim_s,
            "cpu_s_per_s": cpu / sim_s, "n_events": len(ev)}, counts


def main() -> None:
    ap = harness.parser(__doc__, quick="demo only, 10 ms spans (needs a CUDA GPU; gsplat's CUDA "
                                       "code is built once first, untimed)")
    ap.add_argument("--cache", type=Path, default=CACHE / "results")
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: all)")
    args = ap.parse_args()
    import numba
    import pandas as pd

    from gs2e.splat.backend import gsplat_status

    ok, why = gsplat_status()
    if not ok:
        harness.report(None, f"HEADLINE: the event stage on gsplat not measured: {why}")
        return
    cases = CASES[:1] if args.quick else CASES

    if args.threads:
        numba.set_num_threads(args.threads)
    for scene, _, _ in cases:
        if not (args.cache / scene / "splat").is_dir():
            raise SystemExit(f"{args.cache / scene / 'splat'} is missing: run "
                             "benchmarks/bench_event_fidelity.py (or bench_event_sampling.py) first")
    demo = args.cache / "demo"
    for backend in ("cpu", "gsplat"):  # compile numba's kernels, build gsplat's CUDA code
        with harness.clock() as t:
            simulate(demo, "mild", "davis346", "fixed", None, backend, 1.0)
        print(f"warm-up {backend}: {t.wall_s:.0f} s", flush=True)
    rows = []
    for scene, sensor, span_ms in cases:
        span_ms = 10.0 if args.quick else span_ms
        for speed in ("mild", "strong"):
            for mode, px in METHODS:
                counts = {}
                for backend in ("cpu", "gsplat"):
                    row, counts[backend] = simulate(args.cache / scene, speed, sensor, mode, px,
                                                    backend, span_ms)
                    rows.append(row)
                l1 = np.abs(counts["gsplat"] - counts["cpu"]).sum() / max(1, counts["cpu"].sum())
                rows[-1]["l1_vs_cpu"] = rows[-2]["l1_vs_cpu"] = float(l1)
                print(rows[-2], "\n", rows[-1], flush=True)
    df = pd.DataFrame(rows)
    csv = harness.write_csv("bench_events_gpu", rows)
    key = ["scene", "speed", "sensor", "method"]
    w = df.pivot_table(index=key, columns="backend", values="wall_s_per_s")
    n = df.pivot_table(index=key, columns="backend", values="n_events")
    r = df.pivot_table(index=key, columns="backend", values="renders")["cpu"]
    table = pd.DataFrame({"renders": r, "cpu wall s/s": w["cpu"], "gsplat wall s/s": w["gsplat"],
                          "speed-up": w["cpu"] / w["gsplat"], "events cpu": n["cpu"],
                          "events gsplat": n["gsplat"],
                          "L1 gsplat vs cpu": df[df.backend == "cpu"].set_index(key).l1_vs_cpu})
    harness.pyplot()  # the Agg backend for pandas' plot
    ax = table[["cpu wall s/s", "gsplat wall s/s"]].plot.bar(figsize=(9, 4.5), logy=True)
    ax.set_ylabel("wall s per simulated s")
    ax.set_xticklabels([" ".join(map(str, i)) for i in table.index], rotation=30, ha="right",
                       fontsize=7)
    png = harness.save_plot(ax.figure, "bench_events_gpu", dpi=110)
    sp = table["speed-up"]
    l1 = table["L1 gsplat vs cpu"]
    harness.report(table.to_string(float_format=lambda x: f"{x:.3g}"),
                   f"HEADLINE: gsplat's event-stage samples run {sp.min():.2f}-{sp.max():.2f}x the CPU "
                   f"renderer's speed ({numba.get_num_threads()} CPU threads); events differ by "
                   f"per-pixel L1 {l1.min():.3f}-{l1.max():.3f}", [csv, png])


if __name__ == "__main__":
    main()
