"""Cold compiles: what numba's first compile of the kernels costs a fresh clone, against a baseline revision (issue 44).

A fresh clone has no numba cache: its first ``gs2e train`` and first ``gs2e
events`` compile every kernel they call (``make demo`` pays this once per
machine, ``make test`` once per worker). Per side (this checkout, and the
gs2e of ``--baseline-rev`` in a git worktree), each command runs twice in a
fresh process on one empty numba cache: cold (compiles and writes the cache)
and warm (loads it). The compile cost is cold - warm CPU seconds; both runs do
the same work on the same inputs. Sides alternate over ``--rounds`` rounds
(each round with caches emptied again), so that a drift of the machine falls
on both.

Inputs: the demo model of ``bench_event_sampling.py``'s cache (built through
the workflow on first use, about 10 minutes): ``gs2e train`` on its SfM output
for ``--iterations`` steps (default 300: past the first densification), and
``gs2e events`` (DVS-Voltmeter, the default config) over ``--span-ms`` of its
``base_mild`` path. Targets: ``host`` and, where the host has AVX-512,
``avx2`` (``NUMBA_CPU_NAME=haswell``): the code most users' machines compile.

    python benchmarks/bench_compile.py [--quick] [--baseline-rev HEAD~1] [--rounds 2]
        [--targets host,avx2]

``--quick``: ``gs2e events`` only, one round, host only (about 3 minutes).
Writes benchmarks/results/bench_compile.csv and .png; the last printed line
is the headline (compile CPU-s per command, baseline -> today).
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

import harness
from event_runs import build_scenes

BASELINE_REV = "e9dcfef"  # main before the kernels' compile units were split (issue 44)


def commands(scene: Path, out: Path, iterations: int, span_ms: float) -> dict[str, list[str]]:
    """The timed commands (``python -m gs2e ...``), by name."""
    py = [sys.executable, "-m", "gs2e"]
    return {
        "train": py + ["train", "--scene", str(scene / "sfm"), "--out", str(out / "train"), "--threads", "2",
                       "--config-json", json.dumps({"max_iterations": iterations})],
        "events": py + ["events", "--model", str(scene / "splat"), "--trajectory",
                        str(scene / "trajectories" / "base_mild.npz"), "-o", str(out / "events"),
                        "--threads", "2", "--set", f"max_duration_s={span_ms / 1000.0}"],
    }


def measure(side: str, root: Path, target: str, name: str, cmd: list[str], out: Path) -> dict:
    """Cold then warm run of ``cmd`` with the gs2e of ``root`` on one empty
    numba cache; CPU seconds of each."""
    with tempfile.TemporaryDirectory(prefix="bench_compile_") as cache:
        env = harness.gs2e_env(root, NUMBA_CACHE_DIR=cache, **harness.ISA_TARGET_ENV[target])
        runs = []
        for _ in ("cold", "warm"):
            shutil.rmtree(out, ignore_errors=True)  # the same work cold and warm: no outputs kept
            out.mkdir()
            r = harness.run_child(cmd, env=env, cwd=root)
            if r.returncode != 0:
                raise SystemExit(f"{side} {name} failed:\n{r.output[-3000:]}")
            runs.append(r)
    cold, warm = runs
    return {"side": side, "target": target, "command": name, "cold_cpu_s": cold.cpu_s,
            "warm_cpu_s": warm.cpu_s, "compile_cpu_s": cold.cpu_s - warm.cpu_s,
            "cold_wall_s": cold.wall_s, "warm_wall_s": warm.wall_s}


def plot(summary: list[dict]) -> Path:
    return harness.plot_against_baseline(
        "bench_compile", [f"{s['command']}\n{s['target']}" for s in summary],
        [s["baseline_compile_cpu_s"] for s in summary], [s["today_compile_cpu_s"] for s in summary],
        "compile CPU-s (cold - warm run)", "numba's cold compiles")


def main() -> int:
    ap = harness.parser(__doc__, quick="gs2e events only, one round, host only (about 3 minutes)",
                        baseline_rev=BASELINE_REV)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--targets", default=None, help="host,avx2 (default: both where the host has AVX-512)")
    ap.add_argument("--iterations", type=int, default=300)
    ap.add_argument("--span-ms", type=float, default=50.0)
    a = ap.parse_args()
    targets = ["host"] if a.quick and not a.targets else harness.isa_targets(a.targets)
    names = ["events"] if a.quick else ["train", "events"]
    rounds = 1 if a.quick else a.rounds
    scene = build_scenes(["demo"])["demo"]
    rows = []
    with harness.baseline_checkout(a.baseline_rev) as base, tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        cmds = commands(scene.resolve(), out, a.iterations, a.span_ms)
        sides = [("today", harness.REPO), ("baseline", base)]
        for k in range(rounds):
            for target in targets:
                for name in names:
                    for side, root in (sides if k % 2 == 0 else sides[::-1]):
                        row = {"round": k, **measure(side, root, target, name, cmds[name], out)}
                        rows.append(row)
                        print(f"  round {k} {target} {name} {side}: compile {row['compile_cpu_s']:.1f} CPU-s "
                              f"(cold {row['cold_cpu_s']:.1f}, warm {row['warm_cpu_s']:.1f})", flush=True)
    summary = []
    for target in targets:
        for name in names:
            med = {side: float(np.median([r["compile_cpu_s"] for r in rows if r["side"] == side
                                          and r["target"] == target and r["command"] == name]))
                   for side in ("today", "baseline")}
            summary.append({"command": name, "target": target, "baseline_compile_cpu_s": round(med["baseline"], 1),
                            "today_compile_cpu_s": round(med["today"], 1),
                            "ratio": round(med["baseline"] / med["today"], 2) if med["today"] > 0 else None})
    import pandas as pd

    files = [harness.write_csv("bench_compile", rows), plot(summary)]
    head = ", ".join(f"{s['command']} ({s['target']}) {s['baseline_compile_cpu_s']:.0f} -> "
                     f"{s['today_compile_cpu_s']:.0f} CPU-s" for s in summary)
    harness.report(pd.DataFrame(summary), f"cold numba compiles against {a.baseline_rev}: {head}", files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
