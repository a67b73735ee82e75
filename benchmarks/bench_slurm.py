"""Benchmark: the full demo workflow run locally vs through the Slurm profile.

One invocation runs the whole workflow (demo -> ingest -> sfm -> train ->
trajectory -> render -> events -> scene metrics -> summary -> report) twice on
the same one-scene table, each in a fresh temporary directory:

1. locally: ``snakemake --cores N`` (the baseline, N = 2 by default);
2. through ``workflow/profiles/slurm`` (``--profile ... --cores N``) on the
   one-node Slurm cluster of ``workflow/scripts/slurm_local.sh``: started
   here if it is not running (installing slurm-wlm + munge when missing needs
   root and apt), and stopped at the end only if this run started it.

For each run it records the wall time, the number of jobs (one benchmark TSV
per job; for Slurm also the sbatch submissions Snakemake reports), the sum of
the jobs' own wall and CPU times from ``results/**/benchmarks/*.tsv`` (what the
jobs compute, measured inside each job) and the rest of the wall time
(scheduling, start-up, polling; the tiny DAG is nearly a chain, so the sum of
job times is close to its critical path). The headline is the Slurm/local wall
ratio and the per-job overhead ``(Slurm wall - local wall) / jobs`` (also
without the jobs' own times, which load on the shared machine makes vary).
slurmctld's submit/start/end times split the Slurm run's extra time into job
start-up inside Slurm and submission + queueing + status polling. It also
checks the Slurm run's outputs against the local run (the pipeline is seeded:
same config -> same bytes): summary.parquet exists in both, every events file
has the same event count and the same bytes, and so has every other product
file (JSON/parquet tables, which carry run times, excepted); any difference
makes the exit status 1.

    python benchmarks/bench_slurm.py --quick   # tiny demo (gs2e.testing.TINY_OVERRIDES)
    python benchmarks/bench_slurm.py           # the default demo (config/scenes.tsv row)

``--quick`` takes about 3-4 minutes on 2 cores, not the house rule's 60 s:
every Slurm job pays a Snakemake start-up inside the job plus the profile's
status polling (first check 5 s after submission, then every 15 s, 25 s, ...),
and a cluster run of the ten jobs cannot be shorter than that. The full mode
takes about 6 min locally plus the Slurm run. Run it with the shared venv
first on PATH (snakemake and the executor plugin live there) and
PYTHONPATH=$PWD; the jobs themselves import gs2e from this checkout. Numba
caches compiled kernels in the checkout: on a cold cache the first run pays
the compilation (measured: train 20 s instead of 6 s, events 9 s instead of
2 s on the tiny demo), so an unmeasured tiny local run fills the cache first
(``--no-warmup`` skips it); the job-time columns show whether both runs ran
warm.

Writes benchmarks/results/bench_slurm[_quick].csv (one row per run),
bench_slurm[_quick]_jobs.csv (per-rule job times) and a .png bar chart; the
last printed line is the headline figure.
"""

from __future__ import annotations

import csv
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from gs2e.report.io import read_results_benchmarks
from gs2e.testing import TINY_OVERRIDES, slurm_local, why_no_slurm_cluster
from harness import REPO, clock, gs2e_env, parser, pyplot, report, save_plot, write_csv

BIN = Path(sys.executable).parent
PROFILE = REPO / "workflow" / "profiles" / "slurm"
PARTITION = "gs2e"


def default_demo_overrides() -> str:
    """The overrides of the ``demo`` row in config/scenes.tsv."""
    path = REPO / "config" / "scenes.tsv"
    lines = [ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    for row in csv.DictReader(lines, delimiter="\t"):
        if row["scene_id"] == "demo":
            return row.get("overrides") or ""
    raise SystemExit(f"{path}: no 'demo' row")


def warmup_overrides(quick: bool) -> str:
    """The tiny demo, with the measured run's event model: numba compiles per
    function and argument types, not sizes, so this fills the kernel cache for
    the measured runs in ~30 s (a cold cache costs the first run ~25 s more)."""
    if quick:
        return TINY_OVERRIDES
    return ";".join(kv for kv in TINY_OVERRIDES.split(";") if not kv.startswith("events."))


def bench_env() -> dict:
    return gs2e_env(REPO, GS2E_SLURM_PARTITION=PARTITION,
                    GS2E_SLURM_DIR=os.environ.get("GS2E_SLURM_DIR", "/tmp/gs2e-slurm"),
                    PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")


def run_workflow(wd: Path, scene: str, overrides: str, cores: int, env: dict,
                 slurm: bool, timeout_s: int, profile: Path = PROFILE) -> tuple[float, str]:
    """Run the whole workflow in ``wd``; returns (wall s, Snakemake's output)."""
    wd.mkdir(parents=True)
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\n{scene}\tdemo\t\t{overrides}\n")
    extra = ["--profile", str(profile)] if slurm else []
    # coreutils `timeout` as well: a stuck status check must end the run and
    # Snakemake must get the chance to cancel its Slurm jobs
    cmd = ["timeout", "-k", "30", str(timeout_s), str(BIN / "snakemake"),
           "--snakefile", str(REPO / "Snakefile"), *extra, "--cores", str(cores),
           "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}"]
    with clock() as t:
        proc = subprocess.run(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, timeout=timeout_s + 90)
    (wd / "snakemake.out").write_text(proc.stdout)
    if proc.returncode != 0:
        raise SystemExit(f"{'Slurm' if slurm else 'local'} run failed (exit {proc.returncode}); "
                         f"output in {wd / 'snakemake.out'}:\n{proc.stdout[-4000:]}")
    return t.wall_s, proc.stdout


def job_times(wd: Path) -> dict[str, tuple[float, float]]:
    """benchmark file stem -> (wall s, CPU s) measured inside each job, in the
    order the jobs finished."""
    rows = sorted(read_results_benchmarks(wd / "results"), key=lambda r: r["path"].stat().st_mtime)
    return {r["job"]: (r["s"], r.get("cpu_time", float("nan"))) for r in rows}


def product_hashes(wd: Path) -> dict[str, str]:
    """sha256 of every product file under results/ except logs, benchmark
    files, the report page and the JSON/parquet tables (these carry run times;
    tests/test_reproducibility.py compares them without their timing keys)."""
    res = wd / "results"
    out = {}
    for p in sorted(res.rglob("*")):
        rel = p.relative_to(res)
        if (not p.is_file() or {"logs", "benchmarks"} & set(rel.parts)
                or p.suffix in (".json", ".parquet") or p.name.startswith("report")):
            continue
        out[str(rel)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def event_files(wd: Path) -> dict[str, tuple[int, str]]:
    """events file path (relative to results/) -> (event count, sha256)."""
    import h5py

    res = wd / "results"
    out = {}
    for h5 in sorted(res.glob("*/events/**/*.h5")):
        with h5py.File(h5, "r") as f:
            n = int(f["events/t"].shape[0])
        out[str(h5.relative_to(res))] = (n, hashlib.sha256(h5.read_bytes()).hexdigest())
    return out


def submissions(out: str) -> dict[str, str]:
    """Slurm job id -> rule (or ``group_<name>`` for a group job), from Snakemake's
    submission messages."""
    return {jid: (kind + "_" + name if kind == "group" else name) for jid, kind, name in re.findall(
        r"has been submitted with SLURM jobid (\d+) \(log: .*?/slurm_logs/(rule|group)_(\w+)/", out)}


def ungrouped_profile(root: Path) -> Path:
    """A copy of the Slurm profile without its job groups (one sbatch per job)."""
    import yaml

    cfg = yaml.safe_load((PROFILE / "config.yaml").read_text())
    cfg.pop("groups", None)
    cfg.pop("group-components", None)
    out = root / "profile_ungrouped"
    out.mkdir(parents=True)
    (out / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    return out


def slurm_job_times(job_ids: list[str], env: dict) -> dict[str, tuple[float, float, float]]:
    """Slurm job id -> (submit, start, end) epoch s from slurmctld (1 s
    resolution; finished jobs stay in squeue for the local cluster's
    MinJobAge). Empty when squeue no longer knows the jobs."""
    from datetime import datetime

    if not job_ids:
        return {}
    proc = subprocess.run(["squeue", "-h", "-t", "all", "-j", ",".join(job_ids), "-o", "%i|%V|%S|%e"],
                          capture_output=True, text=True, env=env, timeout=60)
    out = {}
    for line in proc.stdout.split():
        jid, *stamps = line.split("|")
        try:
            out[jid] = tuple(datetime.fromisoformat(t).timestamp() for t in stamps)
        except ValueError:  # NONE / Unknown: not finished
            continue
    return out


def union_s(intervals: list[tuple[float, float]]) -> float:
    """Total length of the union of [start, end] intervals (s)."""
    total, cur_end = 0.0, float("-inf")
    for a, b in sorted(intervals):
        if b > cur_end:
            total += b - max(a, cur_end)
            cur_end = b
    return total


def collect(wd: Path, wall_s: float, load: float) -> dict:
    """What one finished run produced and how long its jobs took."""
    jobs = job_times(wd)
    summary = wd / "results" / "summary.parquet"
    n_rows = None
    if summary.is_file():
        import pyarrow.parquet as pq

        n_rows = pq.read_metadata(summary).num_rows
    return {"wall_s": wall_s, "load_1min": load, "jobs": jobs, "events": event_files(wd),
            "products": product_hashes(wd),
            "summary_rows": n_rows}


def main() -> None:
    ap = parser(__doc__, quick="tiny demo (gs2e.testing.TINY_OVERRIDES), ~3-4 min; default: the real demo")
    ap.add_argument("--cores", type=int, default=2,
                    help="--cores of both runs (Slurm: CPUs per job; must fit the node)")
    ap.add_argument("--no-warmup", action="store_true",
                    help="skip the unmeasured tiny local run that fills numba's cache first")
    ap.add_argument("--keep", action="store_true", help="keep the run directories")
    ap.add_argument("--ungrouped", action="store_true",
                    help="the profile without its job groups (one sbatch per job): the baseline of "
                         "the groups' saving")
    args = ap.parse_args()

    reason = why_no_slurm_cluster()
    if reason:
        raise SystemExit(f"bench_slurm: no local Slurm cluster: {reason}")
    if args.cores > (os.cpu_count() or 1):
        raise SystemExit(f"--cores {args.cores} exceeds this node's {os.cpu_count()} CPUs "
                         "(the one-node cluster would reject the jobs)")
    demo, scene, overrides = (("tiny demo", "tiny", TINY_OVERRIDES) if args.quick else
                              ("default demo", "demo", default_demo_overrides()))
    timeout_s = 900 if args.quick else 2400
    name = ("bench_slurm_quick" if args.quick else "bench_slurm") + ("_ungrouped" if args.ungrouped else "")
    env = bench_env()
    root = Path(tempfile.mkdtemp(prefix="gs2e-bench-slurm-"))
    started, start_s, ok = False, 0.0, False
    runs: dict[str, dict] = {}
    try:
        if not args.no_warmup:
            wall, _ = run_workflow(root / "warmup", "warmup", warmup_overrides(args.quick),
                                   args.cores, env, False, timeout_s)
            print(f"warm-up run (numba cache; not measured): {wall:.1f} s", flush=True)
            shutil.rmtree(root / "warmup", ignore_errors=True)
        load = os.getloadavg()[0]
        wall, _ = run_workflow(root / "local", scene, overrides, args.cores, env, False, timeout_s)
        runs["local"] = collect(root / "local", wall, load)
        print(f"local run: {wall:.1f} s", flush=True)

        if slurm_local("status", env).returncode != 0:
            with clock() as t:
                proc = slurm_local("start", env, 600)
            start_s = t.wall_s
            if proc.returncode != 0:
                raise SystemExit(f"slurm_local.sh start failed:\n{proc.stderr[-3000:]}")
            started = True
            print(f"started the local Slurm cluster in {start_s:.1f} s", flush=True)
        else:
            print("local Slurm cluster already running: using it (left running)", flush=True)
        load = os.getloadavg()[0]
        profile = ungrouped_profile(root) if args.ungrouped else PROFILE
        wall, out = run_workflow(root / "slurm", scene, overrides, args.cores, env, True, timeout_s, profile)
        runs["slurm"] = collect(root / "slurm", wall, load)
        runs["slurm"]["submitted"] = submissions(out)
        runs["slurm"]["slurm_times"] = slurm_job_times(list(runs["slurm"]["submitted"]), env)
        print(f"Slurm run: {wall:.1f} s", flush=True)
        ok = True
    finally:
        if started:
            stop = slurm_local("stop", env, 120)
            if stop.returncode != 0:
                print(f"WARNING: slurm_local.sh stop failed:\n{stop.stderr[-2000:]}", file=sys.stderr)
        if ok and not args.keep:
            shutil.rmtree(root, ignore_errors=True)
        else:
            print(f"run directories kept in {root}", file=sys.stderr)

    loc, slu = runs["local"], runs["slurm"]
    # ---- verification: the Slurm run made the same products
    problems = []
    n_jobs = len(slu["jobs"])
    n_sub = len(slu["submitted"])
    if set(loc["jobs"]) != set(slu["jobs"]):
        problems.append(f"job sets differ: local {sorted(loc['jobs'])} vs Slurm {sorted(slu['jobs'])}")
    if args.ungrouped and n_sub != n_jobs:
        problems.append(f"{n_sub} sbatch submissions for {n_jobs} jobs")
    if not args.ungrouped and not n_sub < n_jobs:
        problems.append(f"the profile's job groups did not group: {n_sub} sbatch submissions for {n_jobs} jobs")
    for lbl, r in (("local", loc), ("Slurm", slu)):
        if r["summary_rows"] is None:
            problems.append(f"{lbl} run: results/summary.parquet missing")
        if not r["events"]:
            problems.append(f"{lbl} run: no events file")
    if set(loc["events"]) != set(slu["events"]):
        problems.append(f"events files differ: {sorted(loc['events'])} vs {sorted(slu['events'])}")
    same_counts = all(loc["events"][k][0] == slu["events"][k][0] for k in loc["events"] if k in slu["events"])
    same_bytes = all(loc["events"][k][1] == slu["events"][k][1] for k in loc["events"] if k in slu["events"])
    if not same_counts:
        problems.append("event counts differ between the local and the Slurm run")
    n_events = sum(n for n, _ in slu["events"].values())
    identical = "byte-identical" if same_bytes and not problems else "NOT byte-identical"
    differ = sorted(k for k in set(loc["products"]) | set(slu["products"])
                    if loc["products"].get(k) != slu["products"].get(k))
    if differ:
        problems.append(f"{len(differ)} product files differ, e.g. {differ[:5]}")

    # ---- figures
    overhead = (slu["wall_s"] - loc["wall_s"]) / max(n_jobs, 1)
    rows = []
    for mode, r in (("local", loc), ("slurm", slu)):
        compute = sum(s for s, _ in r["jobs"].values())
        cpu = sum(c for _, c in r["jobs"].values())
        rows.append({"demo": demo, "mode": mode, "cores": args.cores, "wall_s": round(r["wall_s"], 1),
                     "ratio_vs_local": round(r["wall_s"] / loc["wall_s"], 2),
                     "jobs": len(r["jobs"]), "job_wall_sum_s": round(compute, 1),
                     "sbatch": n_sub if mode == "slurm" else 0,
                     "groups": ("none" if args.ungrouped else "profile") if mode == "slurm" else "",
                     "job_cpu_sum_s": round(cpu, 1),
                     "non_job_s": round(r["wall_s"] - compute, 1),
                     "overhead_per_job_s": round(overhead, 1) if mode == "slurm" else 0.0,
                     # the same without the jobs' own times (robust to load noise in compute)
                     "non_job_overhead_per_job_s": round(
                         (r["wall_s"] - compute - loc["wall_s"] + sum(x for x, _ in loc["jobs"].values()))
                         / max(n_jobs, 1), 1) if mode == "slurm" else 0.0,
                     "cluster_start_s": round(start_s, 1) if mode == "slurm" else "",
                     "n_events": sum(n for n, _ in r["events"].values()),
                     "events_sha256": ";".join(h[:16] for _, h in r["events"].values()),
                     "summary_rows": r["summary_rows"], "load_1min_at_start": round(r["load_1min"], 2)})
    st = slu["slurm_times"]
    if len(st) == n_sub and n_sub:
        # Where the Slurm run's extra time went. Job start-up: a job's time in
        # Slurm (start -> end) minus its rule's command (the benchmark file).
        # Idle: no job running on the cluster (submission, queueing, status
        # polling, Snakemake's own scheduling); queued: sum of submit -> start,
        # which on a busy node includes waiting for CPUs other jobs hold.
        in_job = sum(e - s for _, s, e in st.values()) - rows[1]["job_wall_sum_s"]
        idle = slu["wall_s"] - union_s([(s, e) for _, s, e in st.values()])
        rows[1].update(slurm_job_startup_s=round(in_job, 1),
                       slurm_rest_s=round(slu["wall_s"] - rows[1]["job_wall_sum_s"] - in_job, 1),
                       slurm_idle_s=round(idle, 1),
                       slurm_queued_sum_s=round(sum(s - q for q, s, _ in st.values()), 1))
        rows[0].update({k: "" for k in rows[1] if k not in rows[0]})
    else:
        print(f"note: squeue knows {len(st)} of the {n_sub} Slurm jobs: no queue/run split", file=sys.stderr)
    files = [write_csv(name, rows)]
    job_rows = [{"job": j, "local_s": round(loc["jobs"][j][0], 2),
                 "slurm_s": round(slu["jobs"].get(j, (float("nan"),))[0], 2),
                 "local_cpu_s": round(loc["jobs"][j][1], 2),
                 "slurm_cpu_s": round(slu["jobs"].get(j, (0, float("nan")))[1], 2)}
                for j in loc["jobs"]]
    files.append(write_csv(f"{name}_jobs", job_rows))

    plt = pyplot()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [1, 2.2]})
    labels = [f"local\n--cores {args.cores}", "Slurm profile\n(1-node cluster)"]
    comp = [r["job_wall_sum_s"] for r in rows]
    rest = [r["non_job_s"] for r in rows]
    ax.bar(labels, comp, 0.55, label="sum of job wall times (compute)")
    if "slurm_job_startup_s" in rows[1]:
        # the Slurm bar split by where its time outside the jobs' commands went
        r = rows[1]
        ax.bar(labels[0], rest[0], 0.55, bottom=comp[0], color="0.6", label="local scheduler")
        ax.bar(labels[1], r["slurm_job_startup_s"], 0.55, bottom=comp[1], color="tab:orange",
               label="job start-up in Slurm (Snakemake in the job)")
        ax.bar(labels[1], r["slurm_rest_s"], 0.55, bottom=comp[1] + r["slurm_job_startup_s"],
               color="tab:purple", label="submission, queueing, status polling")
    else:
        ax.bar(labels, rest, 0.55, bottom=comp, label="rest: scheduling, start-up, polling")
    for i, r in enumerate(rows):
        ax.text(i, r["wall_s"], f"{r['wall_s']:.0f} s", ha="center", va="bottom")
    ax.set_ylabel("wall time (s)")
    ax.set_ylim(0, max(r["wall_s"] for r in rows) * 1.75)
    ax.set_title(f"gs2e {demo}: {n_jobs} jobs, {rows[1]['ratio_vs_local']:.2f}x")
    ax.legend(fontsize=7, loc="upper left")
    x = range(len(job_rows))
    ax2.bar([i - 0.2 for i in x], [r["local_s"] for r in job_rows], 0.4, label="local")
    ax2.bar([i + 0.2 for i in x], [r["slurm_s"] for r in job_rows], 0.4, label="Slurm")
    ax2.set_xticks(list(x), [r["job"] for r in job_rows], rotation=35, ha="right", fontsize=8)
    ax2.set_ylabel("job wall time inside the job (s)")
    ax2.set_title("per-job compute (Snakemake benchmark files)")
    ax2.legend()
    files.append(save_plot(fig, name, dpi=120))

    print(f"{'mode':>6} {'wall s':>8} {'ratio':>6} {'jobs':>5} {'job wall sum':>13} {'job CPU sum':>12} "
          f"{'rest s':>8} {'s/job over local':>17} {'events':>8} {'load':>5}")
    for r in rows:
        print(f"{r['mode']:>6} {r['wall_s']:>8.1f} {r['ratio_vs_local']:>6.2f} {r['jobs']:>5} "
              f"{r['job_wall_sum_s']:>13.1f} {r['job_cpu_sum_s']:>12.1f} {r['non_job_s']:>8.1f} "
              f"{r['overhead_per_job_s']:>17.1f} {r['n_events']:>8} {r['load_1min_at_start']:>5.2f}")
    print(f"\n{'job':>22} {'local s':>8} {'Slurm s':>8}")
    for r in job_rows:
        print(f"{r['job']:>22} {r['local_s']:>8.2f} {r['slurm_s']:>8.2f}")
    if "slurm_job_startup_s" in rows[1]:
        r = rows[1]
        print(f"\nSlurm run, {r['non_job_s']:.1f} s beyond its {n_sub} jobs' commands: job start-up "
              f"inside Slurm (Snakemake in the job) {r['slurm_job_startup_s']:.0f} s, submission + "
              f"queueing + status polling {r['slurm_rest_s']:.0f} s; no job running for "
              f"{r['slurm_idle_s']:.0f} s of {r['wall_s']:.0f} s; sum of queue waits "
              f"{r['slurm_queued_sum_s']:.0f} s")
    if started:
        print(f"\ncluster start (not in the Slurm wall time): {start_s:.1f} s")
    print(f"events: {len(slu['events'])} file(s), {n_events} events, local vs Slurm {identical}; "
          f"{len(slu['products']) - len(differ)} of {len(slu['products'])} product files byte-identical "
          f"(JSON/parquet tables with run times not compared)")
    print(f"overhead per job without the jobs' own times: {rows[1]['non_job_overhead_per_job_s']:.1f} s")
    for p in problems:
        print(f"PROBLEM: {p}")
    report(None, f"full pipeline on the {demo}: local {loc['wall_s']:.0f} s, Slurm "
                 f"({'no job groups' if args.ungrouped else 'job groups'}) {slu['wall_s']:.0f} s "
                 f"({slu['wall_s'] / loc['wall_s']:.1f}x), {n_jobs} jobs in {n_sub} sbatch submissions, "
                 f"{overhead:.1f} s overhead per job; events {identical}", files)
    if problems:
        sys.exit(1)


if __name__ == "__main__":
    main()
