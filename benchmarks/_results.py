"""Where benchmarks write their tables and plots (benchmarks/results/)."""

from __future__ import annotations

import csv
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"
# Real scenes of ../shared/data as scenes-table rows: name -> (layout, input path).
SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
SHARED_SCENES = {"temple_ring": ("folder", SHARED / "temple_ring"),
                 "llff_fern": ("folder", SHARED / "llff_fern" / "images"),
                 "mouse_colmap": ("colmap", SHARED / "mouse_colmap")}


def write_csv(name: str, rows: list[dict]) -> Path:
    """Write rows (dicts with the same keys) to benchmarks/results/<name>.csv."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.csv"
    with open(path, "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    return path


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def median_ms(fn, reps: int) -> float:
    """Median wall time of ``fn()`` in ms over ``reps`` calls, after one
    untimed call (compiles, warms caches)."""
    fn()
    ts = []
    for _ in range(reps):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    ts.sort()
    return 1e3 * (ts[(len(ts) - 1) // 2] + ts[len(ts) // 2]) / 2
