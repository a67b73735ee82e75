"""Speed against error of the CPU Gaussian-splatting trainer.

Held-out PSNR/SSIM (every 8th view) against wall-clock training time, read
from each run's ``curve.parquet``, for the configured defaults ("gs2e") and,
measured in the same run, a baseline that trains the official way: full
resolution from the start and SH degree 3 ("full-res"; same Gaussian budget,
since an unbounded official-style run does not fit in a CPU benchmark).
Both get the same number of steps; the ratio reported is how much faster
gs2e reaches the baseline's final held-out PSNR.

Scenes: ``--quick`` a small demo scene with ground-truth poses (16 views at
128x96, under 60 s); full mode the demo scene (36 views 320x240, through
ingest + sfm like the pipeline) and ../shared/data/temple_ring (47 real
photos, 640x480, ingest + sfm). Prepared scenes are cached in ``--work``.
The paper's bar for real object scenes is 29.8 dB PSNR / 0.92 SSIM (30k
iterations on a GPU).

Writes benchmarks/results/bench_train.csv (every curve point) and
bench_train.png; the last printed line is the headline.
"""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("GS2E_PROGRESS", "0")

# first: importing gs2e sets OMP_WAIT_POLICY before torch loads
from gs2e.config import load_section  # noqa: E402

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import harness  # noqa: E402
from train_runs import prepare  # noqa: E402

PAPER_PSNR, PAPER_SSIM = 29.8, 0.92
# scaled with the run length; densify_every and eval_every are not (rounds that come
# too often explode the Gaussian count; evaluations are the curve's resolution)
STEP_KEYS = ("min_iterations", "sh_increase_every", "densify_from", "densify_until",
             "opacity_reset_every", "checkpoint_every")


def scaled(cfg: dict, iterations: int) -> dict:
    """The schedule of ``cfg`` compressed/stretched to ``iterations`` steps."""
    f = iterations / cfg["max_iterations"]
    out = dict(cfg, max_iterations=iterations)
    for k in STEP_KEYS:
        out[k] = max(1, int(round(cfg[k] * f))) if cfg[k] else 0
    out["resolution_schedule"] = [[int(round(s * f)), d] for s, d in cfg["resolution_schedule"]]
    return out


def settings(base: dict) -> dict[str, dict]:
    return {"gs2e": dict(base),
            "full-res": dict(base, resolution_schedule=[[0, 1]], sh_degree=3)}


def run_one(scene_dir: Path, out: Path, cfg: dict, threads: int | None) -> tuple[dict, pd.DataFrame]:
    from gs2e.splat.train import train

    from gs2e.splat.settings import SplatSettings

    st = train(scene_dir, out, SplatSettings.defaults(**cfg), seed=0, threads=threads, resume=False)
    return st, pd.read_parquet(out / "curve.parquet")


def time_to_reach(curve: pd.DataFrame, psnr: float, col: str = "cpu_time_s") -> float:
    """First evaluation time (CPU s by default) with held-out PSNR >= ``psnr``."""
    hit = curve[curve["psnr"] >= psnr]
    return float(hit[col].iloc[0]) if len(hit) else float("nan")


def main() -> int:
    ap = harness.parser(__doc__, quick="small demo scene only (< 60 s)")
    ap.add_argument("--scenes", default=None, help="comma list of demo, temple_ring (full mode)")
    ap.add_argument("--iterations", type=int, default=None,
                    help="steps per run (schedule scaled to it); default: quick 300, full 1500")
    ap.add_argument("--no-baseline", action="store_true", help="only the gs2e defaults")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--data", type=Path, default=harness.SHARED, help="shared data folder (../shared/data)")
    ap.add_argument("--name", default="bench_train", help="stem of the CSV/PNG files written")
    ap.add_argument("--work", type=Path, default=harness.RESULTS / "work_train", help="scene/model cache")
    a = ap.parse_args()

    scenes = ["demo-small"] if a.quick else (a.scenes or "demo,temple_ring").split(",")
    if "temple_ring" in scenes and not (a.data / "temple_ring").exists():
        print(f"skipping temple_ring: {a.data / 'temple_ring'} is absent")
        scenes.remove("temple_ring")
    if not scenes:
        print("train: nothing to run")
        return 0
    iters = a.iterations or (300 if a.quick else 1500)
    base = scaled(load_section("splat"), iters)
    if a.quick:
        base["eval_every"] = 50
        base["densify_every"] = min(base["densify_every"], 50)
    a.work.mkdir(parents=True, exist_ok=True)

    rows, finals = [], []
    for scene in scenes:
        with harness.clock() as t:
            sdir = prepare(a.work, scene, a.data)
        print(f"[{scene}] scene ready in {t.wall_s:.1f} s: {sdir}", flush=True)
        for name, cfg in settings(base).items():
            if a.no_baseline and name != "gs2e":
                continue
            st, curve = run_one(sdir, a.work / f"model_{scene}_{name}", cfg, a.threads)
            for r in curve.to_dict("records"):
                rows.append({"scene": scene, "setting": name, **r})
            finals.append({"scene": scene, "setting": name, "iterations": st["iterations"],
                           "stop": st["stop_reason"], "train_s": st["train_time_s"], "cpu_s": st.get("train_cpu_s"),
                           "s_per_it": st["train_time_s"] / st["iterations"],
                           "gaussians": st["n_gaussians"], "budget": st["budget"],
                           "sh": st["sh_degree"], "psnr": st["test_psnr"], "ssim": st["test_ssim"]})
            f = finals[-1]
            print(f"[{scene}/{name}] {f['iterations']} it ({f['stop']}) {f['train_s']:.1f} s "
                  f"({f['s_per_it']:.3f} s/it, {f['cpu_s']:.0f} CPU-s), {f['gaussians']} Gaussians (budget {f['budget']}, "
                  f"SH {f['sh']}): PSNR {f['psnr']:.2f} dB SSIM {f['ssim']:.4f}", flush=True)

    df = pd.DataFrame(rows)
    fin = pd.DataFrame(finals)
    files = [harness.write_csv(a.name, df), harness.write_csv(f"{a.name}_final", fin)]

    print("\nheld-out PSNR/SSIM against training time (every evaluation):")
    with pd.option_context("display.width", 160, "display.max_rows", 400):
        print(df[["scene", "setting", "iteration", "train_time_s", "cpu_time_s", "psnr", "ssim",
                  "n_gaussians", "downscale"]].to_string(index=False, float_format=lambda v: f"{v:.3f}"))
        print("\nfinal:")
        print(fin.to_string(index=False, float_format=lambda v: f"{v:.3f}"))

    ratios = {}
    for scene in scenes:
        g = df[(df.scene == scene) & (df.setting == "gs2e")]
        b = df[(df.scene == scene) & (df.setting == "full-res")]
        if len(b) and len(g):
            # within 0.1 dB of the baseline's final PSNR: the evaluation grid is coarse
            target = float(b["psnr"].iloc[-1]) - 0.1
            tg, tb = time_to_reach(g, target), time_to_reach(b, target)
            ratios[scene] = (target, tg, tb, tb / tg if tg == tg else float("nan"))
            print(f"[{scene}] {target:.2f} dB (baseline final - 0.1): baseline after {tb:.1f} CPU-s, "
                  f"gs2e after {tg:.1f} CPU-s -> {ratios[scene][3]:.2f}x less CPU")
    files.append(plot(df, scenes, a.name))

    heads = []
    for scene in scenes:
        f = fin[(fin.scene == scene) & (fin.setting == "gs2e")].iloc[0]
        extra = f", {ratios[scene][3]:.2f}x less CPU than full-res to {ratios[scene][0]:.1f} dB" \
            if scene in ratios and np.isfinite(ratios[scene][3]) else ""
        heads.append(f"{scene} {f['psnr']:.2f} dB / SSIM {f['ssim']:.3f} in {f['train_s']:.0f} s "
                     f"({f['iterations']} it, {f['gaussians']} G){extra}")
    harness.report(None, f"train: {'; '.join(heads)} (paper bar {PAPER_PSNR} dB / {PAPER_SSIM} SSIM)",
                   files)
    return 0


def plot(df: pd.DataFrame, scenes: list[str], stem: str) -> Path:
    """Held-out PSNR and SSIM against training wall time, per scene and
    setting, as benchmarks/results/<stem>.png; returns the path."""
    plt = harness.pyplot()
    fig, axes = plt.subplots(2, len(scenes), figsize=(5.5 * len(scenes), 7), squeeze=False)
    for j, scene in enumerate(scenes):
        for name, g in df[df.scene == scene].groupby("setting"):
            axes[0, j].plot(g["train_time_s"], g["psnr"], "o-", ms=3, label=name)
            axes[1, j].plot(g["train_time_s"], g["ssim"], "o-", ms=3, label=name)
        axes[0, j].axhline(PAPER_PSNR, ls="--", c="gray", label="paper bar (GPU, 30k it)")
        axes[1, j].axhline(PAPER_SSIM, ls="--", c="gray", label="paper bar (GPU, 30k it)")
        axes[0, j].set_title(scene)
        axes[0, j].set_ylabel("held-out PSNR (dB)")
        axes[1, j].set_ylabel("held-out SSIM")
        axes[1, j].set_xlabel("training wall time (s, 2 CPU cores)")
        axes[0, j].legend(fontsize=8)
    return harness.save_plot(fig, stem, dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
