"""Benchmark: PIE-Net-Lite fine-tuned on gs2e data, against its shipped weights.

The data is ``make finetune``'s results folder (``results/finetune_data``,
built by ``gs2e dataset`` from ``config/finetune.yaml`` and
``config/finetune.tsv``: every real capture of ``../shared/data`` plus the demo
scene at the dataset's settings (DAVIS346, the three speeds of each base path)
with DVS-Voltmeter events over the first 1.5 s, each scene checked against the
dataset's quality gates). The
fine-tuning is one child process, ``gs2e bench-finetune``
(gs2e.bench.finetune), timed by its own rusage: it trains on the ``--train``
scenes (by default every scene that passed its gates in the folder's
``scene_status.parquet``, except the held-out ones) and scores the shipped and
the fine-tuned weights on the held-out ``--eval`` scenes' trajectories and on
the two real recordings with APS frames (slider_depth, DAVIS346 street), each
from a reset state, after EVREAL's robust normalisation (1st / 99th
percentiles), PSNR and SSIM.

The baseline is the shipped network in the same run, scored on the same frames.

    make finetune                      # the data, then this script
    python benchmarks/bench_finetune.py [--quick] [--root results/finetune_data]

Writes benchmarks/results/bench_finetune[_quick].csv (per sequence) and .png
(loss against CPU time; PSNR per sequence before and after), and the weights
to benchmarks/results/bench_finetune[_quick]/; the last line printed is the headline.
"""

from __future__ import annotations

import sys
from pathlib import Path

from harness import REPO, RESULTS, SHARED, parser, pyplot, report, run_child, save_plot, write_csv

EVAL = "llff_fern,demo"
PASSED = "passed"  # --train's default: every scene that passed its gates, less the held-out
REAL = (SHARED / "slider_depth", SHARED / "events" / "davis346_street_aps.aedat4")


def passed_scenes(root: Path, held_out: list[str]) -> list[str]:
    """The scenes of ``root``'s ``scene_status.parquet`` (``gs2e dataset``) that
    passed their gates, less ``held_out``; exits with a message where there is none."""
    from gs2e.dataset.run import STATUS_FILE
    from gs2e.metrics.table import read_table

    status = root / STATUS_FILE
    if not status.is_file():
        sys.exit(f"{status}: no scene status; build the data with `gs2e dataset` (make finetune) "
                 "or name the scenes with --train")
    st = read_table(status)
    return [s for s in st.loc[st["status"] == "passed", "scene_id"] if s not in held_out]


def per_sequence(scores):
    """One row per (data, sequence): mean PSNR / SSIM shipped and fine-tuned."""
    import pandas as pd

    g = scores.groupby(["data", "sequence", "weights"], sort=False).agg(
        frames=("frame", "count"), psnr=("psnr", "mean"), ssim=("ssim", "mean")).reset_index()
    w = g.pivot_table(index=["data", "sequence", "frames"], columns="weights", values=["psnr", "ssim"],
                      sort=False)
    out = pd.DataFrame({"psnr_shipped": w[("psnr", "shipped")], "psnr_finetuned": w[("psnr", "finetuned")],
                        "ssim_shipped": w[("ssim", "shipped")], "ssim_finetuned": w[("ssim", "finetuned")]})
    out["psnr_gain_db"] = out["psnr_finetuned"] - out["psnr_shipped"]
    return out.reset_index().round(3)


def pooled(scores, data: str) -> tuple[float, float]:
    """Mean PSNR over every frame of ``data`` (held-out or real), shipped and fine-tuned."""
    d = scores[scores["data"] == data]
    return tuple(float(d[d["weights"] == w]["psnr"].mean()) for w in ("shipped", "finetuned"))


def plot(history, table, name: str) -> Path:
    plt = pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [1, 1.6]})
    a.plot(history["cpu_s"] / 60.0, history["loss"], lw=0.8, color="0.6", label="per step")
    a.plot(history["cpu_s"] / 60.0, history["loss"].rolling(20, min_periods=1).mean(), lw=2, label="mean of 20")
    a.set_xlabel("training CPU time (min)")
    a.set_ylabel("training loss (L1 after robust normalisation)")
    a.set_title("fine-tuning on gs2e data")
    a.legend()
    a.grid(alpha=0.3)
    x = range(len(table))
    b.bar([i - 0.2 for i in x], table["psnr_shipped"], 0.4, label="shipped")
    b.bar([i + 0.2 for i in x], table["psnr_finetuned"], 0.4, label="fine-tuned")
    b.set_xticks(list(x), [f"{s}\n({d})" for s, d in zip(table["sequence"], table["data"])],
                 rotation=30, ha="right", fontsize=8)
    b.set_ylabel("mean PSNR (dB, robust-normalised)")
    b.set_title("PIE-Net-Lite before and after, on data it was not trained on")
    b.legend()
    b.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return save_plot(fig, name)


def main() -> None:
    import json

    import pandas as pd

    ap = parser(__doc__, quick="8 steps, real data: slider_depth only (about 2 min)")
    ap.add_argument("--root", default=str(REPO / "results" / "finetune_data"),
                    help="results folder of config/finetune.tsv (make finetune)")
    ap.add_argument("--train", default=PASSED, help="scenes to train on, comma-separated (default: every "
                    "scene that passed its gates in the folder's scene_status.parquet, less --eval)")
    ap.add_argument("--eval", default=EVAL, help=f"held-out scenes (default {EVAL})")
    ap.add_argument("--steps", type=int, default=None, help="optimiser steps (default: gs2e's)")
    args = ap.parse_args()
    root = Path(args.root)
    if not (root / "summary.parquet").exists():
        sys.exit(f"{root}: no finished workflow run here; `make finetune` builds it")
    name = "bench_finetune_quick" if args.quick else "bench_finetune"
    out = RESULTS / name
    train = (",".join(passed_scenes(root, args.eval.split(","))) if args.train == PASSED else args.train)
    if not train:
        sys.exit(f"{root}: no scene passed its gates outside the held-out {args.eval}")
    cmd = [sys.executable, "-m", "gs2e", "bench-finetune", "--root", str(root), "--train", train,
           "--eval", args.eval, "--out", str(out)]
    cmd += [a for p in (REAL[:1] if args.quick else REAL) for a in ("--real", str(p))]
    steps = 8 if args.quick and args.steps is None else args.steps
    if steps is not None:
        cmd += ["--steps", str(steps)]
    run = run_child(cmd, cwd=REPO)
    if run.returncode != 0:
        sys.exit(f"gs2e bench-finetune failed:\n{run.output[-3000:]}")
    scores = pd.read_parquet(out / "scores.parquet")
    history = pd.read_parquet(out / "history.parquet")
    info = json.loads((out / "run.json").read_text())
    table = per_sequence(scores)
    files = [write_csv(name, table), plot(history, table, name)]
    train_min = info["train_cpu_s"] / 60.0
    print(f"gs2e bench-finetune: {run.wall_s:.0f} s wall, {run.cpu_s / 60:.1f} CPU-min in all "
          f"({train_min:.1f} training, {info['settings']['steps']} steps on {info['train_intervals']} "
          f"intervals of {len(info['train'])} scenes: {', '.join(info['train'])}), peak RSS {run.peak_rss_mb:.0f} MB")
    held, real = pooled(scores, "heldout"), {r: pooled(scores[scores["sequence"] == r], "real")
                                             for r in dict.fromkeys(scores[scores["data"] == "real"]["sequence"])}
    report(table, "headline: PIE-Net-Lite fine-tuned on gs2e data, mean PSNR shipped -> fine-tuned: "
           f"held-out gs2e scenes ({args.eval}) {held[0]:.2f} -> {held[1]:.2f} dB ({held[1] - held[0]:+.2f}); "
           + "; ".join(f"real {r} {a:.2f} -> {b:.2f} dB ({b - a:+.2f})" for r, (a, b) in real.items())
           + f"; {run.cpu_s / 60:.1f} CPU-min in all", files)


if __name__ == "__main__":
    main()
