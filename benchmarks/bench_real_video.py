"""Benchmark: video reconstruction on real events with real frames, beside gs2e's synthetic ones.

Two real recordings of ../shared/data (see its SOURCES.md), each with the
sensor's own APS frames as ground truth:

* ``slider_depth``: ECD, DAVIS240C (240 x 180) on a linear slider past a static
  table-top scene; the first 50,000 events (0.17 s): the APS frames 1-4 after
  the keyframe 0;
* ``davis346_street_aps``: a static DAVIS346 (346 x 260) over a street with moving cars,
  2.36 s, 59 APS frames (time: the middle of each frame's exposure).

Every method reconstructs each APS frame after the first from the events
between (``gs2e bench-real``, gs2e.bench.real_video): direct integration and the complementary filter
(``gs2e.bench.video.reconstruct``, crossover ``bench.video_cf_alpha_rad_s``)
from the first APS frame, with a nominal contrast of ``--theta`` (0.2) for ON
and OFF (the sensors' own thresholds are not known here: not fitted) and the
APS value taken as linear intensity in [0, 1]; PIE-Net and PIE-Net-Lite
(``gs2e.bench.learned``) from a reset state, never seeing a frame; and, as a
reference, the keyframe held (what the events have to improve on). Scores
(PSNR, SSIM against the 8-bit APS frame / 255, as EVREAL does): the learned
methods after EVREAL's robust normalisation (1st / 99th percentiles), the
model-free ones as they are; the same protocol as the video task of ``gs2e
bench``. The synthetic rows are that task's on ``make demo``'s trajectories
(``results/demo/bench/video``), when present.

    python benchmarks/bench_real_video.py [--quick] [--results results]

Writes benchmarks/results/bench_real_video[_quick].csv (per frame) and .png;
the last line printed is the headline.
"""

from __future__ import annotations

import math
from pathlib import Path


from harness import REPO, SHARED, clock, parser, pyplot, report, save_plot, write_csv

METHODS = ("integrate", "complementary", "pienet", "pienet_lite", "keyframe_held")


def run_recording(rec, theta: float, alpha_rad_s: float) -> list[dict]:
    """Per-frame rows of every method on one recording (gs2e bench-real's, with
    the keyframe held as the reference)."""
    from gs2e.bench.learned import VARIANTS
    from gs2e.bench.real_video import run_recording as run

    return [{"data": "real", **r} for r in run(rec, theta, alpha_rad_s, tuple(VARIANTS))]


def synthetic_rows(results: Path) -> list[dict]:
    """The video task's rows on ``make demo``'s trajectories (none if absent)."""
    import pandas as pd

    rows = []
    for f in sorted((results / "demo" / "bench" / "video").glob("*.parquet")):
        d = pd.read_parquet(f)
        for r in d.itertuples():
            rows.append({"data": "synthetic", "recording": f"demo {f.stem} ({r.model})",
                         "method": r.method, "frame": int(r.frame), "t_rel_s": float(r.t_rel_s),
                         "n_events": int(r.n_events), "psnr": float(r.psnr), "ssim": float(r.ssim),
                         "mse": float(r.mse), "time_s": float(r.time_s)})
    return rows


def summary(df):
    g = df.groupby(["data", "recording", "method"], sort=False)
    s = g.agg(frames=("frame", "count"), psnr=("psnr", "mean"), ssim=("ssim", "mean"),
              s_per_frame=("time_s", "mean")).reset_index()
    return s.round({"psnr": 2, "ssim": 3, "s_per_frame": 3})


def plot(df, name: str) -> Path:
    plt = pyplot()
    real = df[df["data"] == "real"]
    recs = list(dict.fromkeys(real["recording"]))
    fig, axes = plt.subplots(1, len(recs), figsize=(5.5 * len(recs), 3.6), squeeze=False)
    for ax, rec in zip(axes[0], recs):
        for m in METHODS:
            d = real[(real["recording"] == rec) & (real["method"] == m)]
            ax.plot(d["t_rel_s"], d["psnr"], marker="o", ms=3, label=m)
        ax.set_title(f"{rec} (real APS frames)")
        ax.set_xlabel("time after the keyframe (s)")
        ax.set_ylabel("PSNR (dB)")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    return save_plot(fig, name)


def main() -> None:
    from gs2e.events.recordings import read_recording
    from gs2e.config import load_section

    ap = parser(__doc__, quick="slider_depth only (4 frames, about 20 s)")
    ap.add_argument("--theta", type=float, default=0.2,
                    help="nominal contrast of the model-free methods (log step, ON and OFF)")
    ap.add_argument("--results", default=str(REPO / "results"),
                    help="make demo's results folder (the synthetic rows)")
    args = ap.parse_args()
    import pandas as pd

    alpha = float(load_section("bench")["video_cf_alpha_rad_s"])
    with clock() as run:
        rows = run_recording(read_recording(SHARED / "slider_depth"), args.theta, alpha)
        if not args.quick:
            rows += run_recording(read_recording(SHARED / "events" / "davis346_street_aps.aedat4"),
                                  args.theta, alpha)
        rows += synthetic_rows(Path(args.results))
    df = pd.DataFrame(rows)
    name = "bench_real_video_quick" if args.quick else "bench_real_video"
    files = [write_csv(name, df), plot(df, name)]
    s = summary(df)
    print(f"ran in {run.wall_s:.0f} s")

    def mean(rec, m):
        v = s[(s["recording"] == rec) & (s["method"] == m)]["psnr"]
        return float(v.iloc[0]) if len(v) else math.nan

    recs = list(dict.fromkeys(s[s["data"] == "real"]["recording"]))
    report(s, "headline: real APS frames, mean PSNR (dB) " + "; ".join(
        f"{r}: PIE-Net {mean(r, 'pienet'):.2f}, -Lite {mean(r, 'pienet_lite'):.2f}, "
        f"integration {mean(r, 'integrate'):.2f}, complementary {mean(r, 'complementary'):.2f}, "
        f"keyframe held {mean(r, 'keyframe_held'):.2f}"
        for r in recs), files)


if __name__ == "__main__":
    main()
