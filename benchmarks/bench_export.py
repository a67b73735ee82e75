"""Benchmark: export time and size per format, and DataLoader throughput.

For every trajectory of a results tree whose events cover at least two
frames, exports it in each format (gs2e.export) and records wall time, CPU
time and size; then iterates gs2e.data.EventWindowDataset (voxel grids, 5
bins, sharp + blurred frames + depth) with a DataLoader of 2 workers and,
as the baseline measured in the same run, in the main process (0 workers).

The tree is ``--results`` (default: results/ when it holds a trajectory with
covered windows); otherwise (and always with ``--quick``) the tiny demo run by
the tests, with events simulated over its whole trajectory, built once under
benchmarks/results/export_tree/ and reused. Writes
benchmarks/results/bench_export.csv and .png; the last line is the headline.

    python benchmarks/bench_export.py [--quick] [--results DIR]
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

from harness import REPO, RESULTS, clock, parser, pyplot, report, save_plot, write_csv

# the export section's defaults, with EventNeRF's fixed sensor padded or cropped to
CFG_OVERRIDES = {"eventnerf_fit": "pad"}


def tiny_tree() -> Path:
    """The tests' tiny demo with events over the whole trajectory (built once)."""
    from gs2e.testing import TINY_OVERRIDES, run_tiny_pipeline

    wd = RESULTS / "export_tree"
    if not (wd / "results" / "summary.parquet").exists():
        shutil.rmtree(wd, ignore_errors=True)
        run_tiny_pipeline(wd, TINY_OVERRIDES.replace("events.max_duration_s=0.03",
                                                      "events.max_duration_s=null"))
    return wd / "results"


def trajectories(results: Path) -> list[tuple[Path, str]]:
    """(scene_dir, trajectory) pairs whose events cover two consecutive frames."""
    from gs2e.export.windows import read_windows

    out = []
    for w in sorted(results.glob("*/windows/*.parquet")):
        df, _ = read_windows(w)
        if df["inter_covered"].any():
            out.append((w.parent.parent, w.stem))
    return out


def bench_exports(pairs, reps: int) -> list[dict]:
    from gs2e.common.errors import GS2EError
    from gs2e.export.settings import ExportSettings
    from gs2e.export.formats import FORMATS
    from gs2e.export.run import export_trajectory

    cfg = ExportSettings.defaults(**CFG_OVERRIDES)

    rows = []
    for scene_dir, traj in pairs:
        for fmt in FORMATS:
            best = None
            for _ in range(reps):
                with tempfile.TemporaryDirectory() as tmp:
                    try:
                        with clock() as t:
                            man = export_trajectory(scene_dir, traj, fmt, Path(tmp) / "out", cfg)
                    except GS2EError as exc:
                        rows.append({"scene": scene_dir.name, "trajectory": traj, "format": fmt,
                                     "frames": None, "wall_s": None, "cpu_s": None, "mb": None,
                                     "note": str(exc)[:80]})
                        break
                    wall, cpu = t.wall_s, t.cpu_s
                frames = (man.get("gs2e_frames") or man.get("splits", {}).get("train", {}).get("gs2e_frames")
                          or range(man.get("n_frames", 0)))
                if best is None or wall < best["wall_s"]:
                    best = {"scene": scene_dir.name, "trajectory": traj, "format": fmt,
                            "frames": len(frames), "wall_s": round(wall, 3), "cpu_s": round(cpu, 3),
                            "mb": round(man["bytes"] / 1e6, 3), "note": "; ".join(man["warnings"])[:80]}
            if best:
                rows.append(best)
    return rows


def bench_loader(results: Path, workers: int, epochs: int) -> tuple[int, float]:
    """(windows per epoch, windows per second) over ``epochs`` epochs."""
    from torch.utils.data import DataLoader

    from gs2e.data import EventWindowDataset, collate_windows

    ds = EventWindowDataset(results, representation="voxel", n_bins=5)
    dl = DataLoader(ds, batch_size=4, num_workers=workers, collate_fn=collate_windows,
                    persistent_workers=workers > 0)
    next(iter(dl))  # start-up (worker processes, first file opens) not counted
    n = 0
    with clock() as t:
        for _ in range(epochs):
            for b in dl:
                n += len(b["frame"])
    return len(ds), n / t.wall_s


def main() -> None:
    ap = parser(__doc__, quick="the tiny tree, one repetition (< 60 s once built)")
    ap.add_argument("--results", type=Path, help="results tree to use")
    args = ap.parse_args()
    os.environ.setdefault("GS2E_PROGRESS", "0")
    results = args.results or REPO / "results"
    pairs = [] if args.quick else trajectories(results)
    if not pairs:
        results = tiny_tree()
        pairs = trajectories(results)
    rows = bench_exports(pairs, 1 if args.quick else 3)
    n_win, w0 = bench_loader(results, 0, 1 if args.quick else 3)
    _, w2 = bench_loader(results, 2, 1 if args.quick else 3)
    for r in rows:
        r.update(windows=n_win)
    csv_path = write_csv("bench_export", rows + [
        {"scene": "all", "trajectory": "all", "format": f"dataloader_{k}_workers", "frames": None,
         "wall_s": None, "cpu_s": None, "mb": None, "note": f"{v:.1f} windows/s", "windows": n_win}
        for k, v in ((0, w0), (2, w2))])

    plt = pyplot()
    ok = [r for r in rows if r["wall_s"] is not None]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6))
    labels = [f"{r['format']}\n{r['trajectory']}" if len(pairs) > 1 else r["format"] for r in ok]
    a1.bar(range(len(ok)), [r["wall_s"] for r in ok])
    a1.set_xticks(range(len(ok)), labels, rotation=45, ha="right", fontsize=7)
    a1.set_ylabel("export wall time (s)")
    a2.bar(range(len(ok)), [r["mb"] for r in ok], color="tab:orange")
    a2.set_xticks(range(len(ok)), labels, rotation=45, ha="right", fontsize=7)
    a2.set_ylabel("export size (MB)")
    fig.suptitle(f"gs2e export on {results} ({len(pairs)} trajectories)", fontsize=9)
    png = save_plot(fig, "bench_export", dpi=120)

    table = [f"{'scene':>8} {'trajectory':>14} {'format':>13} {'frames':>6} {'wall s':>7} {'CPU s':>7} "
             f"{'MB':>8}  note"]
    for r in rows:
        f = lambda v, p: "-" if v is None else f"{v:.{p}f}"  # noqa: E731
        table.append(f"{r['scene']:>8} {r['trajectory']:>14} {r['format']:>13} {r['frames'] or '-':>6} "
                     f"{f(r['wall_s'], 2):>7} {f(r['cpu_s'], 2):>7} {f(r['mb'], 2):>8}  {r['note']}")
    report("\n".join(table),
           f"DataLoader over {n_win} windows (voxel 5 bins + rgb + blur + depth, batch 4): "
           f"{w0:.1f} windows/s in the main process, {w2:.1f} windows/s with 2 workers", [csv_path, png])


if __name__ == "__main__":
    main()
