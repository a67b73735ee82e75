"""Benchmark: demo-scene generation speed (gs2e.demo ray caster).

Times the whole ``generate_demo_scene`` on the default config and, per view,
the chunked ray caster (rays cast 2^15 at a time, what gs2e uses) against the
baseline of casting all rays of a view in one batch, measured in the same run
on the same views. Writes benchmarks/results/bench_demo.csv and .png; the
last printed line is the headline figure.

    python benchmarks/bench_demo.py [--quick]
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import harness
from gs2e.demo.io import generate_demo_scene
from gs2e.demo.settings import DemoSettings
from gs2e.demo.world import RAY_CHUNK, build_world, intrinsics, orbit_c2w, render_view, wall_size


def time_views(world, c2ws, W, H, ss, chunk) -> float:
    """CPU seconds per view (process time: robust to other jobs on the machine)."""
    fx, fy, cx, cy = intrinsics(W, H, 50.0)
    render_view(world, c2ws[0], fx, fy, cx, cy, W, H, ss, chunk)  # warm-up
    with harness.clock() as t:
        for c in c2ws:
            render_view(world, c, fx, fy, cx, cy, W, H, ss, chunk)
    return t.cpu_s / len(c2ws)


def main() -> None:
    ap = harness.parser(__doc__, quick="fewer views per setting (< 60 s)")
    args = ap.parse_args()
    n = 4 if args.quick else 12
    world = build_world(0, *wall_size(3.0))
    c2ws = orbit_c2w(n, 3.0, 25.0, 8.0)
    rows = []
    for W, H, ss in [(160, 120, 2), (320, 240, 1), (320, 240, 2), (640, 480, 2)]:
        base = time_views(world, c2ws, W, H, ss, chunk=W * H * ss * ss)
        fast = time_views(world, c2ws, W, H, ss, chunk=RAY_CHUNK)
        rows.append({"width": W, "height": H, "supersample": ss, "rays_per_view": W * H * ss * ss,
                     "s_per_view_one_batch": round(base, 4), "s_per_view_chunked": round(fast, 4),
                     "speedup": round(base / fast, 2), "mrays_per_s": round(W * H * ss * ss / fast / 1e6, 2)})

    cfg = DemoSettings.defaults()
    with tempfile.TemporaryDirectory() as tmp:
        with harness.clock() as t:
            stats = generate_demo_scene(Path(tmp) / "demo", cfg)
    wall, cpu = t.wall_s, t.cpu_s

    files = [harness.write_csv("bench_demo", rows)]
    plt = harness.pyplot()

    labels = [f"{r['width']}x{r['height']}\nss{r['supersample']}" for r in rows]
    x = range(len(rows))
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.bar([i - 0.2 for i in x], [r["s_per_view_one_batch"] for r in rows], 0.4,
           label="one batch (baseline)")
    ax.bar([i + 0.2 for i in x], [r["s_per_view_chunked"] for r in rows], 0.4, label=f"chunks of {RAY_CHUNK} rays")
    ax.set_xticks(list(x), labels)
    ax.set_ylabel("CPU s per view")
    ax.set_title("gs2e demo-scene ray caster (1 core)")
    ax.legend()
    files.append(harness.save_plot(fig, "bench_demo"))

    table = [f"{'resolution':>12} {'ss':>3} {'rays':>9} {'one batch s':>12} {'chunked s':>10} {'speedup':>8} "
             f"{'Mray/s':>7}"]
    for r in rows:
        table.append(f"{r['width']:>6}x{r['height']:<5} {r['supersample']:>3} {r['rays_per_view']:>9} "
                     f"{r['s_per_view_one_batch']:>12.3f} {r['s_per_view_chunked']:>10.3f} {r['speedup']:>8.2f} "
                     f"{r['mrays_per_s']:>7.2f}")
    default = next(r for r in rows if (r["width"], r["supersample"]) == (320, 2))
    harness.report("\n".join(table), f"demo-scene default ({stats['n_views']} views 320x240 ss2, "
                   f"{stats['n_points']} points): {wall:.2f} s wall, {cpu:.2f} s CPU; chunked caster "
                   f"{default['speedup']:.2f}x faster than one batch", files)


if __name__ == "__main__":
    main()
