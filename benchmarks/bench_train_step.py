"""One DAVIS346 training step by CPU time, today's code against a baseline revision's (issue 44).

On the DAVIS346 cost model's trained real models (temple_ring and llff_fern of
../shared/data at 349x260 and 348x261, built by ``bench_cost_model.py --run
temple_ring llff_fern --sensor davis346``), one whole training step (render,
0.8 L1 + 0.2 D-SSIM, the hand-written backward, Adam) in the dtype the
cost model's training ran in (today's ``compute_dtype: auto``: float32), on both
sides. Each measurement is a fresh worker process importing one side's gs2e
(this checkout, or a git worktree of ``--baseline-rev`` with its own numba
cache), 2 threads, median CPU ms of ``--steps`` steps after 5 untimed ones;
the sides alternate over ``--rounds`` rounds, so that a drift of the machine
falls on both. CPU time (the process's, all threads), not wall time: issue 44
counts CPU, and wall medians of the same code scatter by 10-20 % here.

    python benchmarks/bench_train_step.py [--quick] [--scenes temple_ring,llff_fern]
        [--rounds 2] [--steps 48] [--baseline-rev 783ff0e]

``--quick``: temple_ring, one round of 16 steps (about 3 minutes: each side
compiles its kernels once), on bench_event_sampling.py's model (built and
cached through the workflow if absent) where the cost model's run is absent. Writes benchmarks/results/bench_train_step.csv and
.png; the last printed line is the headline (baseline over today per scene).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

import harness  # noqa: E402
from harness import REPO, RESULTS  # noqa: E402

BASELINE_REV = "783ff0e"  # main when issue 44 was filed
COST_RUNS = RESULTS / "cost_davis346" / "results"


def worker(scene: str, steps: int, root: str, runs: Path = COST_RUNS) -> dict:
    """Median CPU ms of a training step of ``scene`` (a results folder under
    ``runs``) with the gs2e of ``root``."""
    import numba
    import torch

    harness.check_gs2e_root(root)
    from gs2e.splat.strategy import PARAMS, Adam

    numba.set_num_threads(2)
    torch.set_num_threads(2)
    train_step = harness.train_step_function()
    params, sh, cams, targets, (W, H), dtype = harness.cost_model_step_inputs(runs / scene)
    p = {k: v.clone() for k, v in params.items()}
    opt = Adam({k: 1e-4 for k in PARAMS})
    bg, i = torch.zeros(3), [0]

    def step():
        j = i[0] % len(cams)
        train_step(p, opt, cams[j], targets[j], bg, sh, "cpu", dtype, 0.2)
        i[0] += 1

    for _ in range(4):  # with the median's own untimed call: 5 steps before timing
        step()
    return {"scene": scene, "size": f"{W}x{H}", "dtype": dtype, "gaussians": int(params["means"].shape[0]),
            "step_cpu_ms": harness.median_cpu_ms(step, steps)}


def measure(side: str, root: Path, scene: str, steps: int, cache: Path, runs: Path) -> dict:
    env = harness.gs2e_env(root, NUMBA_CACHE_DIR=str(cache / side))
    r = harness.run_child([sys.executable, str(Path(__file__).resolve()), "--worker", scene,
                           "--steps", str(steps), "--root", str(root), "--runs", str(runs)],
                          env=env, cwd=root)
    if r.returncode != 0:
        raise SystemExit(f"{side} on {scene} failed:\n{r.output[-2000:]}")
    return {"side": side, **json.loads(r.output.strip().splitlines()[-1])}


def plot(summary: list[dict]) -> Path:
    return harness.plot_against_baseline(
        "bench_train_step", [f"{s['scene']}\n{s['ratio']:.2f}x" for s in summary],
        [s["baseline_ms"] for s in summary], [s["today_ms"] for s in summary],
        "CPU ms per training step", "DAVIS346 training step (median, 2 threads)")


def main() -> int:
    ap = harness.parser(__doc__, quick="temple_ring, one round of 16 steps (about 3 minutes)",
                        baseline_rev=BASELINE_REV)
    ap.add_argument("--scenes", default="temple_ring,llff_fern")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=48)
    ap.add_argument("--runs", type=Path, default=COST_RUNS,
                    help="results folder holding the scenes' models (default: the DAVIS346 cost "
                         "model's; benchmarks/results/bench_event_sampling_cache/results holds "
                         "bench_event_sampling.py's models)")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--root", help=argparse.SUPPRESS)
    a = ap.parse_args()
    a.runs = a.runs.resolve()  # workers run in their own checkout
    if a.worker:
        print(json.dumps(worker(a.worker, a.steps, a.root, a.runs)), flush=True)
        return 0
    scenes = ["temple_ring"] if a.quick else a.scenes.split(",")
    rounds, steps = (1, 16) if a.quick else (a.rounds, a.steps)
    missing = [s for s in scenes if not (a.runs / s / "splat" / "train_stats.json").exists()]
    if missing and a.quick and a.runs == COST_RUNS.resolve():
        # --quick without the cost model's run: bench_event_sampling.py's model,
        # built through the workflow (cached) if absent
        from event_runs import build_scenes

        a.runs = build_scenes(scenes)[scenes[0]].parent.resolve()
        print(f"no DAVIS346 cost-model run: --quick measures the models under {a.runs}", flush=True)
        missing = [s for s in scenes if not (a.runs / s / "splat" / "train_stats.json").exists()]
    if missing:
        raise SystemExit(f"no trained model of {', '.join(missing)} under {a.runs}: run "
                         f"python benchmarks/bench_cost_model.py --run {' '.join(missing)} --sensor davis346")
    rows = []
    with harness.baseline_checkout(a.baseline_rev) as base, tempfile.TemporaryDirectory() as tmp:
        sides = [("today", REPO), ("baseline", base)]
        for r in range(rounds):
            for scene in scenes:
                for side, root in (sides if r % 2 == 0 else sides[::-1]):
                    row = {"round": r, **measure(side, root, scene, steps, Path(tmp), a.runs)}
                    rows.append(row)
                    print(f"  round {r} {scene} {side}: {row['step_cpu_ms']:.1f} ms", flush=True)
    summary = []
    for scene in scenes:
        med = {side: float(np.median([x["step_cpu_ms"] for x in rows if x["scene"] == scene and x["side"] == side]))
               for side in ("today", "baseline")}
        first = next(x for x in rows if x["scene"] == scene)
        summary.append({"scene": scene, "size": first["size"], "dtype": first["dtype"],
                        "gaussians": first["gaussians"], "baseline_ms": round(med["baseline"], 1),
                        "today_ms": round(med["today"], 1), "ratio": med["baseline"] / med["today"]})
    import pandas as pd

    table = pd.DataFrame(summary).round({"ratio": 2})
    files = [harness.write_csv("bench_train_step", rows), plot(summary)]
    head = ", ".join(f"{s['scene']} {s['baseline_ms']:.0f} -> {s['today_ms']:.0f} ms ({s['ratio']:.2f}x)"
                     for s in summary)
    harness.report(table, f"DAVIS346 training step, CPU per step against {a.baseline_rev}: {head}", files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
