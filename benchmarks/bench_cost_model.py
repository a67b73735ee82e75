"""Cost model: CPU time and peak memory per stage from Snakemake's benchmark files,
extrapolated to the paper's 1050 scenes.

Reads ``<results>/<scene>/benchmarks/<job>.tsv`` (Snakemake's ``benchmark:``
files: wall s, max_rss MB, cpu_time s; CPU time and peak memory exact from the
gs2e usage line of the job's log, which Snakemake's 30 s samples undercount by up
to 30 CPU-s per job) of one or more finished runs, groups
jobs into stages (``render_<traj>`` -> render, ``events_<traj>`` -> events),
and gives per stage: jobs per scene (render and events: one per trajectory in
the config given, ``render.trajectories``), wall and CPU time per job, CPU
minutes per scene, peak RSS over all jobs, a suggested ``mem_mb`` (2x the
peak, rounded up to 500 MB) and the CPU-hours for N scenes (mean per scene
over the measured scenes, times N). ``demo_scene`` (generated input, not part
of a real scene's cost) and ``summary`` (once per dataset) are listed but not
multiplied by N. The baseline is the measured scene itself (N = 1); the
headline is the CPU-hours for N scenes and the largest job's memory.

    python benchmarks/bench_cost_model.py [--results DIR ...] [--scenes 1050]
                                          [--trajectories 4] [--scale train=405 ...] [--quick]
    python benchmarks/bench_cost_model.py --run temple_ring llff_fern --sensor davis346
    python benchmarks/bench_cost_model.py --run mouse_colmap --sensor imx636

Default results: the repository's results/ (after `make demo`). ``--run`` first
runs the workflow (2 cores) on real scenes of ``../shared/data`` with the paper's
selection of trajectories and its trajectory and event settings
(``config/paper.yaml`` without its 30k training steps: the default recipe with
its plateau stop) at the ``--sensor`` chosen, into
``benchmarks/results/cost_<sensor>/``, then models what it measured.
Writes benchmarks/results/bench_cost_model.csv (per stage), bench_cost_model_jobs.csv
(per job) and bench_cost_model.png (``bench_cost_model_<sensor>*`` with ``--run``);
the last line printed is the headline.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import harness
from harness import REPO, RESULTS, SHARED_SCENES

from gs2e.report.io import read_results_benchmarks

DEFAULT_RESULTS = REPO / "results"
STAGES = ("demo_scene", "ingest", "sfm", "train", "trajectory", "render", "events", "windows", "export",
          "bench", "metrics", "summary")
PER_TRAJECTORY = ("render", "events", "windows", "export", "bench")
NOT_SCALED = ("demo_scene", "summary")


def run_workflow(scenes: list[str], sensor: str, cores: int) -> Path:
    """Run the workflow on real scenes with config/paper.yaml's trajectory, render
    and event settings (training: the default recipe) at ``sensor``; returns
    the results dir. Finished jobs are kept (Snakemake reruns nothing)."""
    import subprocess

    import yaml

    work = RESULTS / f"cost_{sensor}"
    work.mkdir(parents=True, exist_ok=True)
    rows = ["scene_id\tlayout\tpath\toverrides"]
    for sc in scenes:
        layout, path = SHARED_SCENES[sc]
        if not path.exists():
            raise SystemExit(f"{path} is absent")
        rows.append(f"{sc}\t{layout}\t{path}\t")
    (work / "scenes.tsv").write_text("\n".join(rows) + "\n")
    paper = yaml.safe_load((REPO / "config" / "paper.yaml").read_text())
    cfg = {k: v for k, v in paper.items() if k not in ("splat", "scenes", "results_dir")}
    cfg["events"] = {**cfg.get("events", {}), "sensor": sensor}
    cfg.update(scenes=str(work / "scenes.tsv"), results_dir=str(work / "results"))
    (work / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    cmd = [str(Path(sys.executable).parent / "snakemake"),
           *[str(work / "results" / sc / "metrics.parquet") for sc in scenes],
           "--cores", str(cores), "--rerun-incomplete", "--snakefile", str(REPO / "Snakefile"),
           "--directory", str(REPO),
           "--configfile", str(REPO / "config" / "config.yaml"), str(work / "config.yaml")]
    print("running:", " ".join(cmd), flush=True)
    with open(work / "snakemake.log", "w") as log:
        proc = subprocess.run(cmd, stdout=log, stderr=subprocess.STDOUT)
    if proc.returncode:
        raise SystemExit(f"the workflow failed (exit {proc.returncode}); see {work / 'snakemake.log'}")
    return work / "results"


def stage_of(job: str) -> str:
    """Benchmark file stem -> stage (render_<traj> -> render, export_<fmt> -> export)."""
    if job == "bench_summary":
        return "summary"
    for s in PER_TRAJECTORY:
        if job.startswith(s + "_"):
            return s
    return job


def read_jobs(results: Path) -> list[dict]:
    """One dict per benchmark file: scene, job, stage, wall_s, cpu_s, max_rss_mb, mean_load;
    cpu_s and max_rss_mb are exact where the job's log has gs2e's usage line
    (``usage_exact`` 1), with Snakemake's samples beside them (``cpu_s_sampled``)."""
    return [{"results": str(results), "scene": r["scene"] or "(dataset)", "job": r["job"],
             "stage": stage_of(r["job"]), "wall_s": r.get("s", math.nan),
             "cpu_s": r.get("cpu_time", math.nan), "max_rss_mb": r.get("max_rss", math.nan),
             "mean_load": r.get("mean_load", math.nan), "usage_exact": r.get("usage_exact", 0.0),
             "cpu_s_sampled": r.get("cpu_time_sampled", r.get("cpu_time", math.nan)),
             "max_rss_mb_sampled": r.get("max_rss_sampled", r.get("max_rss", math.nan))}
            for r in read_results_benchmarks(results)]


def scene_info(results: Path, scene: str) -> str:
    """Short description of what was measured (views, size, training steps) from metrics.parquet."""
    p = results / scene / "metrics.parquet"
    if not p.is_file():
        return ""
    try:
        import pandas as pd

        r = pd.read_parquet(p).iloc[0]
        w, h = r.get("events_width"), r.get("events_height")
        psnr = r.get("train_test_psnr", math.nan)
        return (f"{int(r['sfm_n_views'])} views, events {int(w)}x{int(h)}, {int(r['train_iterations'])} "
                f"steps, {int(r['train_n_gaussians'])} Gaussians, held-out {psnr:.2f} dB")
    except Exception as exc:  # a partial or older table: describe nothing rather than fail
        return f"(metrics unreadable: {exc.__class__.__name__})"


def scene_megapixels(results: Path, scene: str) -> float:
    """Rendered image size (W x H of the events stage, = the SfM-undistorted views) in megapixels."""
    p = results / scene / "metrics.parquet"
    try:
        import pandas as pd

        r = pd.read_parquet(p, columns=["events_width", "events_height"]).iloc[0]
        return float(r["events_width"]) * float(r["events_height"]) / 1e6
    except Exception:
        return math.nan


def rss_fit(jobs: list[dict]) -> tuple[float, float] | None:
    """Least-squares peak RSS (MB) = a + b * megapixels over jobs with a known size;
    None unless at least two distinct sizes were measured."""
    pts = [(j["megapixels"], j["max_rss_mb"]) for j in jobs if math.isfinite(j.get("megapixels", math.nan))]
    xs = sorted({round(x, 3) for x, _ in pts})
    if len(xs) < 2 or xs[-1] < 1.5 * xs[0]:
        return None
    n = len(pts)
    mx = sum(x for x, _ in pts) / n
    my = sum(y for _, y in pts) / n
    b = sum((x - mx) * (y - my) for x, y in pts) / sum((x - mx) ** 2 for x, _ in pts)
    return my - b * mx, b


def round_up(x: float, step: int) -> int:
    return int(math.ceil(x / step) * step) if math.isfinite(x) else 0


def model(jobs: list[dict], n_traj: int, n_scenes: int, at_mp: float = 2.07,
          measured_traj: int | None = None) -> list[dict]:
    """Per-stage cost model (see the module docstring): jobs per scene as
    measured (mean over the scenes that ran the stage), per-trajectory stages
    scaled from ``measured_traj`` to ``n_traj`` trajectories."""
    scenes = sorted({(j["results"], j["scene"]) for j in jobs if j["scene"] != "(dataset)"})
    out = []
    for stage in STAGES:
        sj = [j for j in jobs if j["stage"] == stage]
        if not sj:
            continue
        per_job_cpu = sum(j["cpu_s"] for j in sj) / len(sj)
        per_job_wall = sum(j["wall_s"] for j in sj) / len(sj)
        ran = {(j["results"], j["scene"]) for j in sj}
        jobs_per_scene = len(sj) / len(ran)
        if stage in PER_TRAJECTORY and measured_traj:
            jobs_per_scene *= n_traj / measured_traj
        jobs_per_scene = round(jobs_per_scene, 2)
        if stage == "summary":
            jobs_per_scene = 0  # once per dataset
        cpu_min_scene = per_job_cpu * jobs_per_scene / 60
        peak = max(j["max_rss_mb"] for j in sj)
        scaled = stage not in NOT_SCALED
        fit = rss_fit(sj)
        out.append({
            "stage": stage, "jobs_measured": len(sj), "scenes_measured": len(scenes),
            "jobs_per_scene": jobs_per_scene,
            "wall_s_per_job": round(per_job_wall, 2), "cpu_s_per_job": round(per_job_cpu, 2),
            "cpu_min_per_scene": round(cpu_min_scene, 3),
            "peak_rss_mb": round(peak, 1), "suggested_mem_mb": max(500, round_up(2 * peak, 500)),
            "max_wall_s": round(max(j["wall_s"] for j in sj), 1),
            "cpu_h_n_scenes": round(cpu_min_scene * n_scenes / 60, 2) if scaled else math.nan,
            "in_extrapolation": scaled,
            "rss_mb_per_mp": round(fit[1], 1) if fit else math.nan,
            f"rss_mb_at_{at_mp:g}mp": round(fit[0] + fit[1] * at_mp) if fit else math.nan,
        })
    return out


def _fmt(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.0f}"


def main() -> int:
    ap = harness.parser(__doc__, quick="no difference: it only reads finished runs' benchmark files "
                                       "(seconds)")
    ap.add_argument("--results", nargs="+", type=Path, default=None,
                    help=f"results dirs of finished runs (default {DEFAULT_RESULTS})")
    ap.add_argument("--scenes", type=int, default=1050, help="scene count to extrapolate to")
    ap.add_argument("--trajectories", type=int, default=None,
                    help="render/events jobs per scene (len(render.trajectories); config/paper.yaml: 4); "
                         "default: as many as the measured scenes had")
    ap.add_argument("--scale", nargs="+", default=[], metavar="STAGE=FACTOR",
                    help="multiply a stage's CPU time by FACTOR (a scaling assumption, e.g. "
                         "train=405 for 15x the steps at 27x the pixels); memory is not scaled")
    ap.add_argument("--at-megapixels", type=float, default=2.07,
                    help="image size for the memory prediction (linear fit of peak RSS in megapixels "
                         "when scenes of different sizes were measured); default 1920x1080")
    ap.add_argument("--run", nargs="+", default=None, choices=sorted(SHARED_SCENES), metavar="SCENE",
                    help=f"first run the workflow on these scenes of ../shared/data ({', '.join(SHARED_SCENES)})")
    ap.add_argument("--sensor", default=None,
                    help="events.sensor for --run (default davis346); names the output files")
    ap.add_argument("--cores", type=int, default=2, help="snakemake --cores for --run")
    args = ap.parse_args()
    if args.run:
        args.sensor = args.sensor or "davis346"
        args.results = [run_workflow(args.run, args.sensor, args.cores)]
    asked = args.results or [DEFAULT_RESULTS]
    jobs = [j for d in asked if d.is_dir() for j in read_jobs(d)]
    if not jobs:
        print(f"no benchmark files found (looked in {', '.join(map(str, asked))}); "
              "run the workflow first (e.g. `make demo`) and pass --results results")
        harness.report(None, "cost model: nothing measured")
        return 0
    per_scene_traj = {}
    for j in jobs:
        if j["stage"] == "render":
            per_scene_traj.setdefault((j["results"], j["scene"]), set()).add(j["job"])
    if args.trajectories:
        n_traj, traj_src = args.trajectories, "--trajectories"
    else:
        n_traj = max((len(v) for v in per_scene_traj.values()), default=1)
        traj_src = "as measured"
    factors = {}
    for item in args.scale:
        stage, _, val = item.partition("=")
        if stage not in STAGES or not val:
            ap.error(f"--scale {item}: expected STAGE=FACTOR with STAGE one of {', '.join(STAGES)}")
        factors[stage] = float(val)
    mp_cache: dict = {}
    for j in jobs:
        key = (j["results"], j["scene"])
        if key not in mp_cache:
            mp_cache[key] = scene_megapixels(Path(j["results"]), j["scene"])
        j["megapixels"] = mp_cache[key]
    name = f"bench_cost_model_{args.sensor}" if args.sensor else "bench_cost_model"
    jobs_csv = harness.write_csv(f"{name}_jobs", jobs)  # as measured
    jobs = [{**j, "cpu_s": j["cpu_s"] * factors.get(j["stage"], 1.0),
             "wall_s": j["wall_s"] * factors.get(j["stage"], 1.0)} for j in jobs]
    measured_traj = max((len(v) for v in per_scene_traj.values()), default=None)
    rows = model(jobs, n_traj, args.scenes, args.at_megapixels, measured_traj)
    csv_path = harness.write_csv(name, rows)

    scenes = sorted({(j["results"], j["scene"]) for j in jobs if j["scene"] != "(dataset)"})
    print("measured scenes:")
    for res, sc in scenes:
        cpu = sum(j["cpu_s"] for j in jobs if (j["results"], j["scene"]) == (res, sc)) / 60
        print(f"  {sc:16s} {cpu:7.1f} CPU-min  {scene_info(Path(res), sc)}  [{res}]")
    n_exact = sum(j["usage_exact"] == 1.0 for j in jobs)
    missed = sum(j["cpu_s"] - j["cpu_s_sampled"] for j in jobs if j["usage_exact"] == 1.0)
    print(f"CPU time and peak memory exact (gs2e's getrusage line in the job's log) for {n_exact} of "
          f"{len(jobs)} jobs; Snakemake's samples missed {missed:.0f} CPU-s of them"
          + ("" if n_exact == len(jobs) else "; the rest are Snakemake's samples (a lower bound)"))
    print(f"trajectories per scene: {n_traj} ({traj_src})"
          + (f"; CPU and wall times scaled by {factors} (assumption, not measured)" if factors else ""))
    hdr = (f"{'stage':11s} {'jobs/scene':>10} {'wall s/job':>10} {'CPU s/job':>9} {'CPU min/scene':>13} "
           f"{'peak RSS MB':>11} {'mem_mb 2x':>9} {f'CPU h x{args.scenes}':>12} "
           f"{'MB/MP':>6} {f'MB@{args.at_megapixels:g}MP':>9}")
    print(hdr)
    for r in rows:
        cph = "-" if not r["in_extrapolation"] else f"{r['cpu_h_n_scenes']:.1f}"
        print(f"{r['stage']:11s} {r['jobs_per_scene']:>10} {r['wall_s_per_job']:>10.1f} "
              f"{r['cpu_s_per_job']:>9.1f} {r['cpu_min_per_scene']:>13.2f} {r['peak_rss_mb']:>11.0f} "
              f"{r['suggested_mem_mb']:>9} {cph:>12} {_fmt(r['rss_mb_per_mp']):>6} "
              f"{_fmt(r[f'rss_mb_at_{args.at_megapixels:g}mp']):>9}")
    scaled = [r for r in rows if r["in_extrapolation"]]
    cpu_min_scene = sum(r["cpu_min_per_scene"] for r in scaled)
    total_h = cpu_min_scene * args.scenes / 60
    peak = max(r["peak_rss_mb"] for r in scaled)
    peak_stage = max(scaled, key=lambda r: r["peak_rss_mb"])["stage"]
    print(f"per scene: {cpu_min_scene:.1f} CPU-min; peak job memory {peak:.0f} MB ({peak_stage})")

    plt = harness.pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    names = [r["stage"] for r in scaled]
    ax[0].bar(names, [r["cpu_h_n_scenes"] for r in scaled])
    ax[0].set(ylabel=f"CPU-hours for {args.scenes} scenes", title=f"total {total_h:.0f} CPU-h")
    ax[1].bar(names, [r["peak_rss_mb"] for r in scaled], label="measured peak RSS")
    ax[1].plot(names, [r["suggested_mem_mb"] for r in scaled], "r_", ms=18, mew=2, label="mem_mb (2x)")
    ax[1].set(ylabel="MB per job", title="memory per job")
    ax[1].legend(fontsize=8)
    for a in ax:
        a.tick_params(axis="x", rotation=45)
    png = harness.save_plot(fig, name, dpi=100)
    wall_min_scene = sum(r["wall_s_per_job"] * r["jobs_per_scene"] for r in scaled) / 60
    harness.report(None, f"cost model: {cpu_min_scene:.1f} CPU-min per scene x {args.scenes} scenes = "
                   f"{total_h:.0f} CPU-hours (CPU/wall {cpu_min_scene / wall_min_scene:.2f} over the "
                   f"measured jobs, run one after another {wall_min_scene * args.scenes / 60:.0f} h); "
                   f"peak memory per job {peak:.0f} MB ({peak_stage}), independent of the scene count",
                   [csv_path, jobs_csv, png])
    return 0


if __name__ == "__main__":
    sys.exit(main())
