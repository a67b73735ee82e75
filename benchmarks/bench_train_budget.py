"""Held-out quality against CPU time on real captures, per Gaussian budget rule.

Scenes: ../shared/data/temple_ring (47 photos) and llff_fern (20 photos), each
ingested at 640 px long side and posed by SfM like the pipeline does (cached
in ``--work``). Settings, each a fresh process on ``--threads`` threads:

- ``auto``: the default recipe (detail budget from edge pixels);
- ``adaptive``: ``splat.budget: adaptive`` (starts there, grows while held-out
  PSNR pays for it; never below the SfM points);
- ``baseline`` (with ``--baseline-repo``): ``auto`` with another checkout's
  code, e.g. a worktree of an older commit, measured in the same run.

Every run trains ``--iterations`` steps (schedule as configured) and records
held-out PSNR/SSIM (every 8th view) against CPU seconds (all threads) every
``eval_every`` steps. The table gives, per scene and setting, the last
evaluation at or before 5, 10 and 20 CPU-minutes (a run that ended earlier
gives its final evaluation, marked ``ended``).

Writes benchmarks/results/bench_train_budget.csv (every curve point),
bench_train_budget_at.csv (the table) and bench_train_budget.png; the last
printed line is the headline (held-out PSNR at 10 CPU-minutes).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))

from _results import RESULTS, pyplot  # noqa: E402
from bench_train import DATA, PHOTOS, prepare  # noqa: E402

SETTINGS = {"auto": {}, "adaptive": {"budget": "adaptive"}}
MARKS_MIN = (5, 10, 20)


def child(repo: str, scene_dir: str, out: str, overrides: str, threads: int) -> None:
    """Train in this process with ``repo``'s code; print the statistics as JSON."""
    sys.path.insert(0, repo)
    import gs2e  # noqa: F401  (first: thread settings before torch loads)
    from gs2e.config import load_section
    from gs2e.splat.train import train

    st = train(scene_dir, out, load_section("splat", overrides), seed=0, threads=threads,
               resume=False)
    print(json.dumps({k: st.get(k) for k in ("iterations", "stop_reason", "train_cpu_s",
                                              "n_gaussians", "budget", "test_psnr", "test_ssim")}))


def run(repo: Path, scene_dir: Path, out: Path, overrides: dict, threads: int):
    import pandas as pd

    if not (out / "curve.parquet").exists():
        env = {**os.environ, "PYTHONPATH": str(repo), "GS2E_PROGRESS": "0"}
        subprocess.run([sys.executable, __file__, "--child", str(repo), str(scene_dir), str(out),
                        json.dumps(overrides), str(threads)], check=True, env=env,
                       capture_output=True)
    stats = json.loads((out / "train_stats.json").read_text())
    return stats, pd.read_parquet(out / "curve.parquet")


def at_marks(curve, stats) -> list[dict]:
    """The last evaluation at or before each mark (CPU-minutes)."""
    rows = []
    for m in MARKS_MIN:
        before = curve[curve["cpu_time_s"] <= 60.0 * m]
        if not len(before):
            rows.append({"cpu_min": m, "psnr": float("nan"), "ssim": float("nan"),
                         "n_gaussians": None, "iteration": None, "ended": False})
            continue
        r = before.iloc[-1]
        ended = len(before) == len(curve)
        rows.append({"cpu_min": m, "psnr": float(stats["test_psnr"] if ended else r["psnr"]),
                     "ssim": float(stats["test_ssim"] if ended else r["ssim"]),
                     "n_gaussians": int(r["n_gaussians"]), "iteration": int(r["iteration"]),
                     "ended": ended})
    return rows


def plot(df, path: Path) -> None:
    plt = pyplot()
    scenes = list(dict.fromkeys(df["scene"]))
    fig, axes = plt.subplots(2, len(scenes), figsize=(5.5 * len(scenes), 7), squeeze=False)
    for j, scene in enumerate(scenes):
        for name, g in df[df.scene == scene].groupby("setting"):
            axes[0, j].plot(g["cpu_time_s"] / 60, g["psnr"], "o-", ms=3, label=name)
            axes[1, j].plot(g["cpu_time_s"] / 60, g["n_gaussians"], "o-", ms=3, label=name)
        for m in MARKS_MIN:
            axes[0, j].axvline(m, ls=":", c="gray")
        axes[0, j].set_title(f"{scene} (640 px)")
        axes[0, j].set_ylabel("held-out PSNR (dB)")
        axes[1, j].set_ylabel("Gaussians")
        axes[1, j].set_xlabel("CPU-minutes (all threads)")
        axes[0, j].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    ap.add_argument("--scenes", default="temple_ring,llff_fern")
    ap.add_argument("--settings", default="auto,adaptive")
    ap.add_argument("--iterations", type=int, default=3000)
    ap.add_argument("--max-side", type=int, default=640)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--baseline-repo", type=Path, default=None,
                    help="another checkout: its code trains the 'auto' setting as 'baseline'")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--work", type=Path, default=RESULTS / "work_train_budget",
                    help="scenes and models (a model folder that exists is reused)")
    a = ap.parse_args()
    if a.child:
        child(*a.child[:4], int(a.child[4]))
        return 0
    import pandas as pd

    a.work.mkdir(parents=True, exist_ok=True)
    runs = [(s, REPO, SETTINGS[s]) for s in a.settings.split(",")]
    if a.baseline_repo:
        runs.append(("baseline", a.baseline_repo.resolve(), {}))
    points, table = [], []
    for scene in a.scenes.split(","):
        if not (a.data / PHOTOS[scene]).exists():
            print(f"skipping {scene}: {a.data / PHOTOS[scene]} is absent")
            continue
        sdir = prepare(a.work, scene, a.data, a.max_side)
        for name, repo, over in runs:
            stats, curve = run(repo, sdir, a.work / f"model_{scene}_{name}",
                               {"max_iterations": a.iterations, **over}, a.threads)
            points += [{"scene": scene, "setting": name, **r} for r in curve.to_dict("records")]
            for r in at_marks(curve, stats):
                table.append({"scene": scene, "setting": name, **r,
                              "final_gaussians": stats["n_gaussians"], "budget": stats["budget"],
                              "run_cpu_min": stats["train_cpu_s"] / 60})
            print(f"[{scene}/{name}] {stats['iterations']} it ({stats['stop_reason']}), "
                  f"{stats['train_cpu_s'] / 60:.1f} CPU-min, {stats['n_gaussians']} Gaussians "
                  f"(budget {stats['budget']}): PSNR {stats['test_psnr']:.2f} dB "
                  f"SSIM {stats['test_ssim']:.4f}", flush=True)
    if not table:
        print("train budget: nothing to run")
        return 0
    df, tab = pd.DataFrame(points), pd.DataFrame(table)
    RESULTS.mkdir(parents=True, exist_ok=True)
    df.to_csv(RESULTS / "bench_train_budget.csv", index=False)
    tab.to_csv(RESULTS / "bench_train_budget_at.csv", index=False)
    plot(df, RESULTS / "bench_train_budget.png")
    with pd.option_context("display.width", 160):
        print(tab.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    ten = tab[tab.cpu_min == 10]
    print("train budget: held-out PSNR at 10 CPU-min, 640 px: " + "; ".join(
        f"{r.scene}/{r.setting} {r.psnr:.2f} dB ({r.n_gaussians} G{', ended' if r.ended else ''})"
        for r in ten.itertuples()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
