"""Held-out quality against CPU time on real captures, per Gaussian budget rule.

Scenes: ../shared/data/temple_ring (47 photos) and llff_fern (20 photos), each
ingested at 640 px long side and posed by SfM like the pipeline does (cached
in ``--work``); ``--scenes demo`` trains the demo scene (ingest + SfM as
the workflow does, 255x191 views). Settings, each a fresh process on
``--threads`` threads:

- ``auto``: the default recipe (detail budget from edge pixels);
- ``adaptive``: ``splat.budget: adaptive`` (starts there, grows while held-out
  PSNR pays for it; never below the SfM points);
- ``baseline`` (with ``--baseline-repo``): ``auto`` with another checkout's
  code, e.g. a worktree of an older commit, measured in the same run.

``--setting NAME=JSON`` (repeatable) adds a setting of splat overrides, e.g.
``--setting late_fine='{"resolution_schedule": [[0, 4], [1000, 2], [2500, 1]]}'``;
``"_seed": N`` in a setting trains with seed N (the seed-to-seed spread, e.g.
``--setting f64='{"compute_dtype": "float64"}' --setting f64_s1='{"compute_dtype":
"float64", "_seed": 1}' --setting s1='{"_seed": 1}'``).

``--cost-run SENSOR`` trains instead on the scenes of
``bench_cost_model.py --run … --sensor SENSOR`` (their SfM outputs under
``benchmarks/results/cost_<sensor>/``) at that sensor's training size, with the
configured plateau stop and max_iterations (unless ``--iterations``):
the cost model's training, with and without a change. The table then also
gives, per setting, the CPU-minutes to come within 0.2 dB of the first
setting's final held-out PSNR (issue 32's bar) and its own final PSNR, and
replays the plateau stop (the configured rule and each ``--replay-stop
PATIENCE,DELTA_DB``) on the recorded curves, each with its setting's own
overrides (a later full-size level changes which evaluations count): where each rule would have
stopped, its PSNR and CPU against patience 3 / 0.1 dB (the rule before
2026-11-26); written to bench_train_budget_stop_rules_<sensor>.csv.

Every run trains ``--iterations`` steps (schedule as configured) and records
held-out PSNR/SSIM (every 8th view) against CPU seconds (all threads) every
``eval_every`` steps. The table gives, per scene and setting, the last
evaluation at or before 5, 10 and 20 CPU-minutes (a run that ended earlier
gives its final evaluation, marked ``ended``).

``--quick``: the small demo scene of bench_train.py (16 views 128x96,
ground-truth poses), 300 steps per setting, evaluated every 50 (about a
minute; a model folder that exists is reused).

A setting that runs another checkout's code is a child process whose
``PYTHONPATH`` is that checkout (:func:`harness.gs2e_env`); it stops if it
imported another gs2e.

Writes benchmarks/results/bench_train_budget.csv (every curve point),
bench_train_budget_at.csv (the table) and bench_train_budget.png; the last
printed line is the headline (held-out PSNR at 10 CPU-minutes).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import harness
from harness import REPO, RESULTS
from train_runs import PHOTOS, prepare

SETTINGS = {"auto": {}, "adaptive": {"budget": "adaptive"}}
MARKS_MIN = (5, 10, 20)


def child(repo: str, scene_dir: str, out: str, overrides: str, threads: int) -> None:
    """Train in this process with ``repo``'s code (the process is started
    with :func:`harness.gs2e_env`); print the statistics as JSON.
    ``overrides`` may hold ``_target_size`` [W, H] (the event sensor's array)
    and ``_seed`` (the training seed, default 0: settings that differ only in
    it give the seed-to-seed spread)."""
    harness.check_gs2e_root(repo)  # imports gs2e first: thread settings before torch loads
    from gs2e.splat.train import train

    over = json.loads(overrides)
    target = over.pop("_target_size", None)
    seed = int(over.pop("_seed", 0))
    try:
        from gs2e.splat.settings import SplatSettings
        cfg = SplatSettings.defaults(**over)
    except ImportError:  # a revision from before typed settings took the section as a dict
        from gs2e.config import load_section
        cfg = load_section("splat", json.dumps(over))
    st = train(scene_dir, out, cfg, seed=seed, threads=threads,
               resume=False, **({"target_size": tuple(target)} if target else {}))
    print(json.dumps({k: st.get(k) for k in ("iterations", "stop_reason", "train_cpu_s",
                                              "n_gaussians", "budget", "test_psnr", "test_ssim")}))


def run(repo: Path, scene_dir: Path, out: Path, overrides: dict, threads: int):
    """Train ``scene_dir`` into ``out`` with ``repo``'s code in a fresh process
    (unless ``out`` holds a run already): (statistics, curve)."""
    import pandas as pd

    if not (out / "curve.parquet").exists():
        subprocess.run([sys.executable, __file__, "--child", str(repo), str(scene_dir), str(out),
                        json.dumps(overrides), str(threads)], check=True, env=harness.gs2e_env(repo),
                       capture_output=True)
    stats = json.loads((out / "train_stats.json").read_text())
    return stats, pd.read_parquet(out / "curve.parquet")


def replay_stop(curve, cfg, patience: int, delta_db: float):
    """The evaluation at which the trainer's plateau stop
    (:func:`gs2e.splat.train.plateau_step`) would have ended this run with
    ``patience`` and ``delta_db``: the run is deterministic, so stopping earlier
    keeps the same curve up to there, and the final model is the one of that
    evaluation. Exact while no opacity reset happened (opacity_reset_every
    beyond the run)."""
    from gs2e.splat.train import plateau_step

    rule = cfg.replace(plateau_patience=patience, plateau_min_delta_db=delta_db)
    best, bad = -float("inf"), 0
    rows = curve.sort_values("iteration")
    for r in rows.itertuples():
        best, bad, stop = plateau_step(best, bad, r.psnr, int(r.iteration), rule)
        if stop:
            return r
    return rows.iloc[-1]


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


def plot(df) -> Path:
    """Held-out PSNR and Gaussians against CPU-minutes, per scene and setting,
    as benchmarks/results/bench_train_budget.png; returns the path."""
    plt = harness.pyplot()
    scenes = list(dict.fromkeys(df["scene"]))
    fig, axes = plt.subplots(2, len(scenes), figsize=(5.5 * len(scenes), 7), squeeze=False)
    for j, scene in enumerate(scenes):
        for name, g in df[df.scene == scene].groupby("setting"):
            axes[0, j].plot(g["cpu_time_s"] / 60, g["psnr"], "o-", ms=3, label=name)
            axes[1, j].plot(g["cpu_time_s"] / 60, g["n_gaussians"], "o-", ms=3, label=name)
        for m in MARKS_MIN:
            axes[0, j].axvline(m, ls=":", c="gray")
        axes[0, j].set_title(scene)
        axes[0, j].set_ylabel("held-out PSNR (dB)")
        axes[1, j].set_ylabel("Gaussians")
        axes[1, j].set_xlabel("CPU-minutes (all threads)")
        axes[0, j].legend(fontsize=8)
    return harness.save_plot(fig, "bench_train_budget", dpi=110)


def main() -> int:
    ap = harness.parser(__doc__, quick="the small demo scene, 300 steps per setting (about a minute)")
    ap.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    ap.add_argument("--scenes", default="temple_ring,llff_fern")
    ap.add_argument("--settings", default="auto,adaptive")
    ap.add_argument("--setting", action="append", default=[], metavar="NAME=JSON",
                    help="a setting of splat overrides (repeatable)")
    ap.add_argument("--cost-run", metavar="SENSOR", default=None,
                    help="train the cost model's scenes at SENSOR's training size (plateau stop)")
    ap.add_argument("--replay-stop", action="append", default=[], metavar="PATIENCE,DELTA_DB",
                    help="with --cost-run: also replay this plateau stop rule on the curves")
    ap.add_argument("--iterations", type=int, default=None,
                    help="steps per run (default 3000, --quick 300; with --cost-run the configured "
                    "max_iterations)")
    ap.add_argument("--max-side", type=int, default=640)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--baseline-repo", type=Path, default=None,
                    help="another checkout: its code trains the 'auto' setting as 'baseline'")
    ap.add_argument("--data", type=Path, default=harness.SHARED)
    ap.add_argument("--work", type=Path, default=RESULTS / "work_train_budget",
                    help="scenes and models (a model folder that exists is reused)")
    a = ap.parse_args()
    if a.child:
        child(*a.child[:4], int(a.child[4]))
        return 0
    import pandas as pd

    settings = dict(SETTINGS)
    for item in a.setting:
        name, _, js = item.partition("=")
        settings[name] = json.loads(js)
        a.settings += f",{name}"
    unknown = [s for s in a.settings.split(",") if s and s not in settings]
    if unknown:
        ap.error(f"--settings: unknown {', '.join(unknown)} (known: {', '.join(settings)}; "
                 "'baseline' comes from --baseline-repo)")
    runs = [(s, REPO, settings[s]) for s in a.settings.split(",") if s]
    if a.baseline_repo:
        runs.insert(0, ("baseline", a.baseline_repo.resolve(), {}))
    if a.quick and a.cost_run:
        ap.error("--quick trains the small demo scene, not the cost model's scenes (--cost-run)")
    if a.quick:
        a.scenes = "demo-small"
    if a.iterations is None:
        a.iterations = 0 if a.cost_run else 300 if a.quick else 3000
    base = {"max_iterations": a.iterations} if a.iterations else {}
    if a.quick:
        base["eval_every"] = 50
    if a.cost_run:
        from gs2e.config import load_config
        import yaml

        from gs2e.events.sensors import get_sensor
        from gs2e.events.settings import event_settings

        cost = RESULTS / f"cost_{a.cost_run}"
        if a.work == RESULTS / "work_train_budget":
            a.work = RESULTS / f"work_train_cost_{a.cost_run}"
        ev = load_config(yaml.safe_load((cost / "config.yaml").read_text()))["events"]
        base["_target_size"] = list(get_sensor(event_settings(ev)).size)
        if a.scenes == "temple_ring,llff_fern" and not (cost / "results" / "llff_fern").exists():
            a.scenes = ",".join(p.name for p in sorted((cost / "results").iterdir()) if (p / "sfm").is_dir())
    def cost_scene(scene: str) -> Path:
        """A scene's SfM output in the cost model's run."""
        return RESULTS / f"cost_{a.cost_run}" / "results" / scene / "sfm"

    a.work.mkdir(parents=True, exist_ok=True)
    for _, repo, _ in runs:  # compile each checkout's numba kernels outside the timings
        if not (a.work / f"warm_{repo.name}").exists():
            first = a.scenes.split(",")[0]
            sdir = cost_scene(first) if a.cost_run else prepare(a.work, first, a.data, a.max_side)
            run(repo, sdir, a.work / f"warm_{repo.name}", {"max_iterations": 30, "min_iterations": 1,
                                                            "eval_every": 10}, a.threads)
    points, table = [], []
    for scene in a.scenes.split(","):
        if a.cost_run:
            sdir = cost_scene(scene)
            if not (sdir / "scene.json").exists():
                print(f"skipping {scene}: {sdir} is absent (run bench_cost_model.py --run first)")
                continue
        elif scene not in ("demo-small", "demo") and not (a.data / PHOTOS[scene]).exists():
            print(f"skipping {scene}: {a.data / PHOTOS[scene]} is absent")
            continue
        else:
            sdir = prepare(a.work, scene, a.data, a.max_side)
        ref_psnr = None
        for name, repo, over in runs:
            stats, curve = run(repo, sdir, a.work / f"model_{scene}_{name}", {**base, **over}, a.threads)
            if ref_psnr is None:
                ref_psnr = stats["test_psnr"]
            near = curve[curve["psnr"] >= ref_psnr - 0.2]
            to_ref = float(near["cpu_time_s"].iloc[0]) / 60 if len(near) else float("nan")
            points += [{"scene": scene, "setting": name, **r} for r in curve.to_dict("records")]
            for r in at_marks(curve, stats):
                table.append({"scene": scene, "setting": name, **r,
                              "final_gaussians": stats["n_gaussians"], "budget": stats["budget"],
                              "run_cpu_min": stats["train_cpu_s"] / 60, "iterations": stats["iterations"],
                              "final_psnr": stats["test_psnr"], "cpu_min_near_first": to_ref})
            print(f"[{scene}/{name}] {stats['iterations']} it ({stats['stop_reason']}), "
                  f"{stats['train_cpu_s'] / 60:.1f} CPU-min, {stats['n_gaussians']} Gaussians "
                  f"(budget {stats['budget']}): PSNR {stats['test_psnr']:.2f} dB "
                  f"SSIM {stats['test_ssim']:.4f}", flush=True)
    if a.cost_run:  # the cost model's own training runs (the workflow's seeds), replayed below
        for curve_path in sorted((RESULTS / f"cost_{a.cost_run}" / "results").glob("*/splat/curve.parquet")):
            curve = pd.read_parquet(curve_path)
            points += [{"scene": curve_path.parents[1].name, "setting": "workflow", **r}
                       for r in curve.to_dict("records")]
    if not table and not points:
        print("train budget: nothing to run")
        return 0
    df, tab = pd.DataFrame(points), pd.DataFrame(table)
    files = [harness.write_csv("bench_train_budget", df), plot(df)]
    if len(tab):
        files.append(harness.write_csv("bench_train_budget_at", tab))
        with pd.option_context("display.width", 160):
            print(tab.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
    if a.cost_run:
        from gs2e.splat.settings import SplatSettings

        cfg = SplatSettings.defaults()
        rules = list(dict.fromkeys([(float(cfg.plateau_patience), float(cfg.plateau_min_delta_db))] + [
            tuple(float(v) for v in r.split(",")) for r in a.replay_stop]))
        rows = []
        for (scene, name), g in df.groupby(["scene", "setting"], sort=False):
            # the setting's own schedule: which evaluations count as full resolution
            own = cfg.replace(**{k: v for k, v in settings.get(name, {}).items() if k in cfg.as_dict()})
            ref = replay_stop(g, own, 3, 0.1)  # the rule of the runs measured before 2026-11-26
            for pat, dl in rules:
                r = replay_stop(g, own, int(pat), dl)
                rows.append({"scene": scene, "setting": name, "patience": int(pat), "min_delta_db": dl,
                             "stop_iteration": int(r.iteration), "psnr": r.psnr,
                             "psnr_gain_db": r.psnr - ref.psnr, "cpu_min": r.cpu_time_s / 60,
                             "cpu_ratio": r.cpu_time_s / ref.cpu_time_s})
        rep = pd.DataFrame(rows)
        files.append(harness.write_csv(f"bench_train_budget_stop_rules_{a.cost_run}", rep))
        print("plateau stop rules replayed on the curves (against patience 3, 0.1 dB):")
        with pd.option_context("display.width", 160):
            print(rep.to_string(index=False, float_format=lambda v: f"{v:.3f}"))
        if not len(tab):
            last = rep[(rep.patience == rules[-1][0]) & (rep.min_delta_db == rules[-1][1])]
            harness.report(None, f"stop rule patience {int(rules[-1][0])}, {rules[-1][1]:g} dB against "
                           "patience 3, 0.1 dB: " + "; ".join(
                               f"{r.scene}/{r.setting} {r.psnr_gain_db:+.2f} dB at {r.cpu_ratio:.2f}x the CPU"
                               for r in last.itertuples()), files)
            return 0
        one = tab[tab.cpu_min == MARKS_MIN[0]]
        harness.report(None, f"training at {a.cost_run}'s size, plateau stop; CPU-min to within 0.2 dB of the "
                       "first setting's final PSNR / whole run, final PSNR: " + "; ".join(
                           f"{r.scene}/{r.setting} {r.cpu_min_near_first:.2f} / {r.run_cpu_min:.2f} CPU-min, "
                           f"{r.final_psnr:.2f} dB ({r.iterations} it)" for r in one.itertuples()), files)
        return 0
    ten = tab[tab.cpu_min == 10]
    size = "demo-small 128x96" if a.quick else f"{a.max_side} px"
    harness.report(None, f"train budget: held-out PSNR at 10 CPU-min, {size}: " + "; ".join(
        f"{r.scene}/{r.setting} {r.psnr:.2f} dB ({r.n_gaussians} G{', ended' if r.ended else ''})"
        for r in ten.itertuples()), files)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
