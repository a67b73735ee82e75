"""Benchmark: whole ``gs2e events`` jobs per sampling setting (issue 67's "Cheap").

Issue 67's cost target is the event stage's CPU per simulated second against
the paper's fixed 2400 fps with today's (cut-window) renderer. Each setting
here runs as the whole command: a fresh process, 2 threads, start-up
included, CPU seconds of all its threads. It runs on the first ``--span-s`` of
a trajectory of the demo models that ``bench_window.py`` trained at DAVIS346
(cut and smooth window; run it first), with DVS-Voltmeter ``dvs346`` and seed
1, each after an untimed job of 0.01 s (which compiles what the setting
needs). The baseline is the cut model at fixed 2400 fps, in the same run. With
``--baseline-rev`` (default: the commit before the one-pass cross-fade), the
smooth-window settings also run with that revision's code, in a git worktree,
so a change to the renderer is measured before and after in one run.

The settings (window: sampling):

* cut: fixed 2400 fps (the baseline);
* smooth: fixed 2400 fps, continuous in time (orders held and cross-faded);
* smooth: fixed 600 fps, 4 points per step on the cubic with each render's
  own slope (a second render 2 us later), and with the slope from the
  tangent pass (``events.sampling.slopes: tangent``);
* smooth: the motion clock at 1 px, 4 points per step on the cubic through
  the renders;
* smooth: the motion clock at 2 px, 8 points per step;
* smooth: the curve clock (``events.sampling.mode: curve``) at an error of
  0.02 and of 0.05 theta, 4 points per step, and at 0.02 with 8 points
  (with the baseline revision's code too where it has that mode).

How faithful each is: ``bench_event_fidelity.py``. Here only its cost, with
its render and event counts.

Usage: python benchmarks/bench_event_jobs.py [--quick] [--span-s 1.0] [--trajectory base_mild]
       [--baseline-rev REV | --baseline-rev ""] [--settings "smooth, fixed 2400;..."]
Writes benchmarks/results/bench_event_jobs[_quick].csv and .png; the last
line printed is the headline.
"""

from __future__ import annotations

import tempfile
from contextlib import nullcontext
from pathlib import Path

import harness
from event_runs import run_events

CACHE = harness.RESULTS / "bench_window_cache" / "demo"
SCENE = harness.RESULTS / "bench_groundtruth_cache" / "full" / "results" / "demo"
BASELINE = "cut, fixed 2400"
SETTINGS = {
    BASELINE: ("cut", {"mode": "fixed", "fixed_fps": 2400.0}),
    "smooth, fixed 2400": ("smooth", {"mode": "fixed", "fixed_fps": 2400.0}),
    "smooth, fixed 600 slopes 4": ("smooth", {"mode": "fixed", "fixed_fps": 600.0, "substeps": 4,
                                              "slopes": "difference"}),
    "smooth, fixed 600 tangent 4": ("smooth", {"mode": "fixed", "fixed_fps": 600.0, "substeps": 4,
                                               "slopes": "tangent"}),
    "smooth, motion 1 cubic 4": ("smooth", {"mode": "motion", "fixed_fps": 2400.0, "max_motion_px": 1.0,
                                            "substeps": 4}),
    "smooth, motion 2 cubic 8": ("smooth", {"mode": "motion", "fixed_fps": 2400.0, "max_motion_px": 2.0,
                                            "substeps": 8}),
    "smooth, curve 0.02 cubic 4": ("smooth", {"mode": "curve", "fixed_fps": 2400.0, "error_fraction": 0.02,
                                              "substeps": 4}),
    "smooth, curve 0.05 cubic 4": ("smooth", {"mode": "curve", "fixed_fps": 2400.0, "error_fraction": 0.05,
                                              "substeps": 4}),
    "smooth, curve 0.02 cubic 8": ("smooth", {"mode": "curve", "fixed_fps": 2400.0, "error_fraction": 0.02,
                                              "substeps": 8}),
}
QUICK = (BASELINE, "smooth, curve 0.05 cubic 4")


def modes_of(code: Path) -> list[str]:
    """The sampling modes the gs2e of checkout ``code`` has (its schema's enum)."""
    import yaml

    schema = yaml.safe_load((Path(code) / "gs2e" / "schemas" / "config.schema.yaml").read_text())
    return schema["properties"]["events"]["properties"]["sampling"]["properties"]["mode"]["enum"]


def run_job(code: Path, window: str, sampling: dict, traj: str, span_s: float, out: Path) -> dict:
    """One ``gs2e events`` job with the gs2e of checkout ``code``
    (:func:`event_runs.run_events`)."""
    cfg = {"model": "voltmeter", "preset": "dvs346", "sensor": "davis346", "sampling": dict(sampling)}
    r = run_events(SCENE, traj, cfg, sampling["mode"], sampling["fixed_fps"], 1.0, 1, span_s, out,
                   repo=code, model=CACHE / window)
    return {"cpu_s": r["cpu_s"], "wall_s": r["wall_s"], "renders": r["stats"]["sampling_renders"],
            "events": r["stats"]["n_events"], "simulated_s": r["stats"]["duration_s"]}


def main() -> None:
    import pandas as pd

    ap = harness.parser(__doc__, quick="0.1 s, the baseline and the curve clock, no baseline code "
                        "(about 1 min)", baseline_rev="48ec9bc")
    ap.add_argument("--span-s", type=float, default=1.0, help="simulated seconds from the path's start")
    ap.add_argument("--trajectory", default="base_mild")
    ap.add_argument("--settings", default=";".join(s for s in SETTINGS if s != BASELINE),
                    help=f"separated by ';', of: {'; '.join(s for s in SETTINGS if s != BASELINE)} "
                    "(the baseline always runs)")
    args = ap.parse_args()
    unknown = [s for s in args.settings.split(";") if s not in SETTINGS]
    if unknown:
        raise SystemExit(f"--settings: unknown {unknown} (of {', '.join(SETTINGS)})")
    if not all((CACHE / w / "model.json").exists() for w in ("cut", "smooth")):
        harness.report(None, f"whole event jobs not measured: no demo models in {CACHE} here "
                       "(benchmarks/bench_window.py --quick trains them)")
        return
    span = 0.1 if args.quick else args.span_s
    names = QUICK if args.quick else (BASELINE, *[s for s in args.settings.split(";") if s != BASELINE])
    rev = "" if args.quick else args.baseline_rev
    rows = []
    with harness.clock() as total, tempfile.TemporaryDirectory() as tmp:
        with harness.baseline_checkout(rev) if rev else nullcontext(None) as checkout:
            for code, label in ((harness.REPO, "today"), (checkout, f"baseline {rev}")):
                if code is None:
                    continue
                modes = modes_of(code)
                for name in names:
                    window, sampling = SETTINGS[name]
                    if label != "today" and (window == "cut" or sampling["mode"] not in modes):
                        continue  # the cut window's renders did not change; a mode it lacks
                    print(f"{label}: {name} ...", flush=True)
                    # untimed first: a fresh worktree compiles its kernels (numba's cache)
                    run_job(Path(code), window, sampling, args.trajectory, 0.01, Path(tmp) / "warm")
                    res = run_job(Path(code), window, sampling, args.trajectory, span,
                                  Path(tmp) / f"{label}_{name}".replace(" ", "_").replace(",", ""))
                    rows.append({"setting": name, "code": label, "machine": harness.machine(),
                                 "trajectory": args.trajectory, **res})
    df = pd.DataFrame(rows)
    base = df[(df.setting == BASELINE) & (df.code == "today")].iloc[0]
    df["cpu_per_sim_s"] = df.cpu_s / df.simulated_s
    df["cpu_ratio"] = df.cpu_per_sim_s / (base.cpu_s / base.simulated_s)
    df["events_vs_baseline"] = df.events / base.events - 1.0
    name = "bench_event_jobs" + ("_quick" if args.quick else "")
    csv = harness.write_csv(name, df.to_dict("records"))
    today = df[df.code == "today"].set_index("setting")
    old = df[df.code != "today"].set_index("setting")
    labels = [n for n in names if n != BASELINE]
    png = harness.plot_against_baseline(  # no baseline code run (--quick): today's bars alone
        name, [n.replace("smooth, ", "") for n in labels],
        [float(old.cpu_ratio[n]) if n in old.index else float("nan") for n in labels],
        [float(today.cpu_ratio[n]) for n in labels], "CPU per simulated s / cut fixed 2400",
        f"gs2e events, demo {args.trajectory}, first {span:g} s")
    print(f"measured in {total.wall_s:.0f} s")
    table = df[["setting", "code", "renders", "events", "events_vs_baseline", "cpu_s", "cpu_ratio"]].round(3)
    ratios = today.drop(BASELINE).cpu_ratio
    head = (f"whole event jobs on the demo's {args.trajectory} ({span:g} s, DAVIS346), CPU against the "
            f"cut window's fixed 2400 fps: " + ", ".join(f"{n} {r:.2f}x" for n, r in ratios.items())
            + ("" if old.empty else f" (baseline {rev}: " + ", ".join(
                f"{n} {r:.2f}x" for n, r in old.cpu_ratio.items()) + ")"))
    harness.report(table, head, [csv, png])


if __name__ == "__main__":
    main()
