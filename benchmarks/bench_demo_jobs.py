"""A finished workflow's jobs rerun with today's code and a baseline revision's, one after the other.

Reads the command line of each chosen job from its log (the first line every
``gs2e`` command writes, ``results/<scene>/logs/<job>.log`` and
``results/logs/<job>.log``), reruns it on the same inputs with the gs2e of this
checkout and with the gs2e of ``--baseline-rev`` (a git worktree), job by job
in turn, outputs redirected to a temporary folder, and measures each run's CPU
seconds (its own rusage: the command and every thread it ran). Each side first compiles its numba
kernels into its own cache by running the cheapest job of each command once,
whole and untimed (a shorter run would leave kernels that only later steps use,
such as densification's, to compile inside the timing), so the timings are those
of a machine where ``make demo`` ran before, as the workflow's own logs are.

Use it for the jobs a change touches; the other jobs' CPU is what their logs
say. For ``make demo``:

    python benchmarks/bench_demo_jobs.py [--jobs 'demo/train,demo/bench_*,bench_real'] [--baseline-rev REV]

``--quick``: the novel-view path's deblurring job only (about a minute).
Writes benchmarks/results/bench_demo_jobs.csv and .png; the last printed line
is the headline (the chosen jobs' CPU, baseline against today).
"""

from __future__ import annotations

import fnmatch
import json
import re
import sys
import tempfile
from pathlib import Path

import harness
from harness import REPO

BASELINE_REV = "621e2f6"  # main before float32 training from the demo's size and float64 SSIM on NCHW
_LINE = re.compile(r"INFO gs2e: gs2e \S+ (?P<args>.*)$")
# flags naming what a job writes: redirected to the run's own folder
_OUTPUTS = ("-o", "--out", "--png", "--checkpoint-dir")


def job_args(log: Path) -> list[str]:
    """The gs2e arguments of the job that wrote ``log`` (its first line)."""
    with open(log) as fh:
        m = _LINE.search(fh.readline().rstrip("\n"))
    if not m:
        raise SystemExit(f"{log}: no gs2e command line on its first line")
    head, sep, cfg = m["args"].partition(" --config-json ")
    return head.split() + (["--config-json", cfg] if sep else [])


def logged_cpu_s(log: Path) -> float:
    """The CPU seconds the job's log reports (nan if it has none)."""
    m = re.findall(r"finished in [0-9.]+ s \(([0-9.]+) CPU-s", log.read_text(errors="replace"))
    return float(m[-1]) if m else float("nan")


def redirect(args: list[str], out: Path, workdir: Path) -> list[str]:
    """``args`` with every output flag's path moved into ``out`` and every
    input path relative to ``workdir`` (where the workflow ran) made absolute:
    the job runs in the checkout it times (``python -m gs2e`` imports the gs2e
    of its working directory first). A job that writes anywhere else (no
    output flag, or ``report``'s default) is refused: it would overwrite the
    workflow's results."""
    if args[0] == "report" or not any(a in _OUTPUTS for a in args):
        raise SystemExit(f"{args[0]}: its outputs cannot be redirected; choose other jobs")
    args = list(args)
    for i, a in enumerate(args):
        if i and args[i - 1] in _OUTPUTS:
            args[i] = str(out / Path(a).name)
        elif "/" in a and not a.startswith(("-", "{")) and (workdir / a).exists():
            args[i] = str((workdir / a).resolve())
    return args


def kind(args: list[str]) -> str:
    """The command a job runs, with its task: ``train``, ``bench deblur``, ..."""
    return " ".join([args[0]] + ([args[args.index("--task") + 1]] if "--task" in args else []))


def side_env(name: str, root: Path, tmp: Path) -> dict:
    """The environment of side ``name``: the gs2e of checkout ``root`` (checked)
    and its own numba cache."""
    env = harness.gs2e_env(root, NUMBA_CACHE_DIR=str(tmp / f"numba_{name}"))
    got = harness.run_child([sys.executable, "-c", "import gs2e; print(gs2e.__file__)"], env=env, cwd=root)
    if not Path(got.output.strip().splitlines()[-1]).resolve().is_relative_to(root.resolve()):
        raise SystemExit(f"{name}: imports {got.output.strip()}, not the gs2e of {root}")
    return env


_UNKNOWN = re.compile(r"config: unknown key (?P<keys>[\w., ]+)")


def without_default_keys(args: list[str], keys: list[str]) -> list[str] | None:
    """``args`` with the dotted ``keys`` (``section.key`` or ``section.sub.key``)
    removed from its ``--config-json``, if each holds its default there (today's
    schema default: a setting an older gs2e does not have, left as it was: the
    same job); None if any does not."""
    from gs2e.config import load_config

    if "--config-json" not in args:
        return None
    i = args.index("--config-json") + 1
    cfg = json.loads(args[i])
    defaults = load_config({})
    for key in keys:
        section, *path = key.split(".")
        node, default = cfg, defaults.get(section, {})
        for part in path[:-1]:
            node, default = node.get(part, {}), default.get(part, {})
        name = path[-1] if path else section
        if name not in node or node[name] != default.get(name, object()):
            return None
        del node[name]
    return args[:i] + [json.dumps(cfg)] + args[i + 1:]


def run_job(name: str, root: Path, env: dict, job: str, log: Path, out: Path, workdir: Path) -> harness.ChildRun:
    out.mkdir(parents=True)
    args = redirect(job_args(log), out, workdir)
    r = harness.run_child([sys.executable, "-m", "gs2e", *args], env=env, cwd=root)
    for _ in range(3):  # a baseline older than some settings, all at their default here
        m = _UNKNOWN.search(r.output) if r.returncode != 0 else None
        args = without_default_keys(args, [k.strip() for k in m["keys"].split(",")]) if m else None
        if args is None:
            break
        r = harness.run_child([sys.executable, "-m", "gs2e", *args], env=env, cwd=root)
    if r.returncode != 0:
        raise SystemExit(f"{name}: {job} failed:\n{r.output[-2000:]}")
    return r


def run_sides(sides: dict[str, Path], jobs: dict[str, Path], tmp: Path, workdir: Path) -> list[dict]:
    """Each side (name -> checkout) compiles by running the cheapest job of
    each command once, untimed; then every job runs on each side in turn, the
    side that goes first alternating, so that a drift of the machine's speed
    and warm file caches fall on both alike."""
    envs = {name: side_env(name, root, tmp) for name, root in sides.items()}
    cheapest: dict[str, str] = {}
    for job, log in sorted(jobs.items(), key=lambda kv: logged_cpu_s(kv[1])):
        cheapest.setdefault(kind(job_args(log)), job)
    for name, root in sides.items():
        for k, job in cheapest.items():
            r = run_job(name, root, envs[name], job, jobs[job], tmp / name / f"warm_{job}", workdir)
            print(f"  {name}: compiled {k} ({r.cpu_s:.0f} CPU-s)", flush=True)
    rows = []
    for n, (job, log) in enumerate(jobs.items()):
        for name, root in (list(sides.items()) if n % 2 == 0 else list(sides.items())[::-1]):
            r = run_job(name, root, envs[name], job, log, tmp / name / job, workdir)
            rows.append({"job": job, "side": name, "cpu_s": round(r.cpu_s, 2), "wall_s": round(r.wall_s, 2),
                         "peak_rss_mb": round(r.peak_rss_mb, 1), "logged_cpu_s": logged_cpu_s(log)})
            print(f"  {name}: {job} {r.cpu_s:.1f} CPU-s", flush=True)
    return rows


def main() -> int:
    ap = harness.parser(__doc__, quick="the novel-view path's deblurring job only (about a minute)",
                        baseline_rev=BASELINE_REV)
    ap.add_argument("--results", type=Path, default=REPO / "results", help="a finished workflow's results_dir")
    ap.add_argument("--workdir", type=Path, default=REPO,
                    help="the directory that workflow ran in (its jobs' relative paths start there)")
    ap.add_argument("--jobs", default="demo/train,demo/bench_*,bench_real",
                    help="comma-separated patterns of jobs: SCENE/LOG for a scene's job, LOG for "
                    "a workflow-wide one (results/logs), e.g. 'demo/bench_deblur_*'")
    a = ap.parse_args()
    patterns = ["demo/bench_deblur_mini00_medium"] if a.quick else a.jobs.split(",")
    logs = sorted(a.results.glob("*/logs/*.log")) + sorted(a.results.glob("logs/*.log"))
    keyed = {f"{lg.parents[1].name}/{lg.stem}" if lg.parents[1] != a.results else lg.stem: lg for lg in logs}
    jobs = {k: lg for k, lg in keyed.items() if any(fnmatch.fnmatch(k, p) for p in patterns)}
    if not jobs:
        raise SystemExit(f"no job log under {a.results} matches {patterns} (run make demo first)")
    print(f"{len(jobs)} jobs: {', '.join(jobs)}", flush=True)
    with tempfile.TemporaryDirectory(prefix="bench_demo_jobs_") as tmp, \
            harness.baseline_checkout(a.baseline_rev) as checkout:
        rows = run_sides({"baseline": checkout, "today": REPO}, jobs, Path(tmp), a.workdir.resolve())
    by = {(r["job"], r["side"]): r["cpu_s"] for r in rows}
    table = [{"job": j, "baseline_cpu_s": by[(j, "baseline")], "today_cpu_s": by[(j, "today")],
              "ratio": round(by[(j, "baseline")] / by[(j, "today")], 2)} for j in jobs]
    files = [harness.write_csv("bench_demo_jobs", rows)]
    plt = harness.pyplot()
    fig, ax = plt.subplots(figsize=(max(6, 0.7 * len(table)), 4))
    x = range(len(table))
    ax.bar([i - 0.2 for i in x], [t["baseline_cpu_s"] for t in table], 0.4, label=f"{a.baseline_rev}", color="0.6")
    ax.bar([i + 0.2 for i in x], [t["today_cpu_s"] for t in table], 0.4, label="today")
    ax.set_xticks(list(x), [t["job"].split("/")[-1] for t in table], rotation=60, ha="right")
    ax.set(ylabel="CPU-s per job", title="a finished workflow's jobs, rerun on the same inputs")
    ax.legend()
    files.append(harness.save_plot(fig, "bench_demo_jobs"))
    base, today = sum(t["baseline_cpu_s"] for t in table), sum(t["today_cpu_s"] for t in table)
    text = "\n".join(f"{t['job']:40s} {t['baseline_cpu_s']:9.1f} {t['today_cpu_s']:9.1f} {t['ratio']:6.2f}x"
                     for t in table)
    harness.report(f"{'job':40s} {a.baseline_rev:>9s} {'today':>9s}\n{text}",
                   f"{len(table)} jobs: {base:.0f} CPU-s with {a.baseline_rev}, {today:.0f} today "
                   f"({base / today:.2f}x less)", files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
