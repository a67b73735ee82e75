"""Benchmark: `gs2e ingest` throughput on real scenes vs a bare decode+PNG-encode loop.

The baseline does the minimum any ingestion must do (cv2.imread + cv2.imwrite
PNG per image, no checks); the ratio shows the cost of gs2e's checks
(duplicate hashing, size reconciliation, atomic output, scene.json).

    python benchmarks/bench_ingest.py [--quick] [--data ../shared/data]

Writes benchmarks/results/bench_ingest.csv and .png; the last line printed is
the headline figure.
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import cv2

from gs2e.io.ingest import ingest_scene
from gs2e.io.settings import IngestSettings
from harness import SHARED, clock, parser, pyplot, report, save_plot, write_csv


def _baseline(files: list[Path], out: Path, max_side: int | None) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for f in files:
        img = cv2.imread(str(f), cv2.IMREAD_COLOR)
        if max_side and max(img.shape[:2]) > max_side:
            s = max_side / max(img.shape[:2])
            img = cv2.resize(img, (round(img.shape[1] * s), round(img.shape[0] * s)),
                             interpolation=cv2.INTER_AREA)
        cv2.imwrite(str(out / (f.stem + ".png")), img, [cv2.IMWRITE_PNG_COMPRESSION, 3])


def main() -> int:
    ap = parser(__doc__, quick="one repetition (under 60 s)")
    ap.add_argument("--data", default=str(SHARED), help="folder of the real scenes")
    args = ap.parse_args()
    os.environ.setdefault("GS2E_PROGRESS", "0")
    data = Path(args.data)
    scenes = [("llff_fern", data / "llff_fern" / "images"), ("temple_ring", data / "temple_ring")]
    scenes = [(n, p) for n, p in scenes if p.is_dir()]
    if not scenes:
        print(f"no real data under {data}; nothing to benchmark")
        return 0
    reps = 1 if args.quick else 3
    rows = []
    tmp = Path(tempfile.mkdtemp(prefix="bench_ingest_"))
    try:
        for name, src in scenes:
            files = sorted(p for p in src.iterdir() if p.suffix.lower() == ".png")
            for max_side in (None, 320):
                t_base, t_ing = [], []
                for r in range(reps):
                    with clock() as t:
                        _baseline(files, tmp / f"base_{name}_{r}", max_side)
                    t_base.append(t.wall_s)
                    with clock() as t:
                        ingest_scene(src, "folder", tmp / f"ing_{name}_{r}",
                                     IngestSettings.defaults(max_side=max_side))
                    t_ing.append(t.wall_s)
                tb, ti = min(t_base), min(t_ing)
                rows.append({"scene": name, "views": len(files), "max_side": max_side or 0,
                             "baseline_s": round(tb, 4), "ingest_s": round(ti, 4),
                             "ingest_img_per_s": round(len(files) / ti, 2),
                             "ratio_ingest_over_baseline": round(ti / tb, 3)})
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    csv_path = write_csv("bench_ingest", rows)
    plt = pyplot()
    labels = [f"{r['scene']}\nmax_side={r['max_side'] or 'full'}" for r in rows]
    x = range(len(rows))
    fig, ax = plt.subplots(figsize=(7, 3.5))
    ax.bar([i - 0.2 for i in x], [r["baseline_s"] for r in rows], 0.4, label="baseline (imread+imwrite)")
    ax.bar([i + 0.2 for i in x], [r["ingest_s"] for r in rows], 0.4, label="gs2e ingest")
    ax.set_xticks(list(x), labels, fontsize=8)
    ax.set_ylabel("wall time (s)")
    ax.legend()
    png = save_plot(fig, "bench_ingest", dpi=100)

    table = [f"{'scene':12s} {'views':>5s} {'max_side':>8s} {'base s':>8s} {'ingest s':>8s} {'img/s':>7s} "
             f"{'ratio':>6s}"]
    for r in rows:
        table.append(f"{r['scene']:12s} {r['views']:5d} {r['max_side'] or 'full':>8} {r['baseline_s']:8.3f} "
                     f"{r['ingest_s']:8.3f} {r['ingest_img_per_s']:7.1f} "
                     f"{r['ratio_ingest_over_baseline']:6.2f}")
    head = next((r for r in rows if r["scene"] == "temple_ring" and not r["max_side"]), rows[0])
    report("\n".join(table),
           f"ingest {head['scene']} full resolution: {head['ingest_img_per_s']:.1f} images/s, "
           f"{head['ratio_ingest_over_baseline']:.2f}x the bare imread+imwrite baseline", [csv_path, png])
    return 0


if __name__ == "__main__":
    sys.exit(main())
