"""Benchmark: planning the workflow over many scenes (`snakemake -n`) - time and memory.

For N synthetic scenes (the paper's mix: 1000/1050 MVImgNet clips, the rest
DL3DV scenes) it creates dataset folders of empty frame files, as many per
scene as the releases hold (what a dry-run needs on disk: ingest's inputs are
a scene's files, listed while planning), writes the scenes table with `gs2e scenes`
(folders checked), and times `snakemake -n --quiet rules` over it, recording
the job count and the peak RSS of the snakemake process (os.wait4). The
baseline is the same dry-run over 1 scene; the headline is the time per scene
at 1050 scenes and its ratio to the 1-scene run. A scheduler whose memory grew
with the scenes' data would show here: RSS should stay ~flat (it holds the
DAG, not images).

    python benchmarks/bench_dryrun.py [--quick] [--configfile config/paper.yaml]

Writes benchmarks/results/bench_dryrun.csv and .png; the last line printed is
the headline figure.
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import sys
import tempfile
from pathlib import Path

from harness import REPO, gs2e_env, parser, pyplot, report, run_child, save_plot, write_csv

BIN = Path(sys.executable).parent
MVIMGNET_FRAMES = 30  # frames of an MVImgNet clip (about 6.5 M frames over 219 k videos)
DL3DV_FRAMES = 300  # frames of a DL3DV scene, one resolution (images_4 of the 960P release)


def make_selection(root: Path, n: int) -> tuple[Path, int, int]:
    """MVImgNet/DL3DV folders of empty frame files and id lists for n scenes (1000:50 mix)."""
    n_dl = round(n * 50 / 1050)
    n_mvi = n - n_dl
    mvi, dl = root / "mvimgnet", root / "dl3dv"
    mvi_ids = [f"{i % 238}/{i:08x}" for i in range(n_mvi)]  # 238 categories as in MVImgNet
    # hash-like ids: a long run of one character would trip Snakemake's periodic-wildcard check
    dl_ids = [f"{(i % 10) + 1}K/{hashlib.sha256(str(i).encode()).hexdigest()}" for i in range(n_dl)]
    # empty frame files, as many as a release holds: ingest's inputs are a scene's
    # files (gs2e.io.selection.source_files), listed while planning
    for i in mvi_ids:
        (mvi / i / "images").mkdir(parents=True)
        for k in range(MVIMGNET_FRAMES):
            (mvi / i / "images" / f"{k:03d}.jpg").touch()
    for i in dl_ids:
        (dl / i / "images_4").mkdir(parents=True)
        (dl / i / "transforms.json").write_text("{}")
        for k in range(DL3DV_FRAMES):
            (dl / i / "images_4" / f"frame_{k:05d}.png").touch()
    (root / "mvi.txt").write_text("\n".join(mvi_ids) + "\n")
    (root / "dl.txt").write_text("\n".join(dl_ids) + "\n" if dl_ids else "")
    return root, n_mvi, n_dl


def run_measured(cmd: list[str], env: dict, cwd: Path) -> tuple[float, int, int, str, float]:
    """(wall s, peak RSS of the process in kB, return code, stdout, CPU s: user +
    system, less sensitive than wall time to other work on the machine)."""
    r = run_child(cmd, env, cwd)
    return r.wall_s, int(round(r.peak_rss_mb * 1024)), r.returncode, r.output, r.cpu_s


def bench_one(n: int, configfile: str | None, tmp: Path) -> dict:
    wd = tmp / f"n{n}"
    wd.mkdir()
    _, n_mvi, n_dl = make_selection(wd, n)
    env = gs2e_env(REPO, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}")
    cmd = [sys.executable, "-m", "gs2e", "scenes", "--out", str(wd / "scenes.tsv")]
    if n_mvi:
        cmd += ["--mvimgnet-root", str(wd / "mvimgnet"), "--mvimgnet-ids", str(wd / "mvi.txt")]
    if n_dl:
        cmd += ["--dl3dv-root", str(wd / "dl3dv"), "--dl3dv-ids", str(wd / "dl.txt")]
    t_sel, rss_sel, rc, text, _ = run_measured(cmd, env, wd)
    if rc != 0:
        raise SystemExit(f"gs2e scenes failed for N={n}:\n{text[-3000:]}")
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), "-n", "--quiet", "rules",
           "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}"]
    if configfile:
        cmd[3:3] = ["--configfile", str(Path(configfile).resolve())]
    wall, rss_kb, rc, text, cpu = run_measured(cmd, env, wd)
    if rc != 0:
        raise SystemExit(f"snakemake -n failed for N={n}:\n{text[-3000:]}")
    m = re.search(r"^total\s+(\d+)\s*$", text, re.M)
    jobs = int(m.group(1)) if m else -1
    return {"n_scenes": n, "n_mvimgnet": n_mvi, "n_dl3dv": n_dl, "jobs": jobs,
            "dryrun_s": round(wall, 3), "dryrun_cpu_s": round(cpu, 3), "ms_per_scene": round(1000 * wall / n, 2),
            "peak_rss_mb": round(rss_kb / 1024, 1), "scenes_cli_s": round(t_sel, 3),
            "scenes_cli_rss_mb": round(rss_sel / 1024, 1)}


def main() -> int:
    ap = parser(__doc__, quick="N = 1 and 200 (under 60 s)")
    ap.add_argument("--configfile", default=None,
                    help="config file on top of config/config.yaml (e.g. config/paper.yaml)")
    ap.add_argument("--sizes", type=int, nargs="+", default=None, help="scene counts to run")
    args = ap.parse_args()
    sizes = args.sizes or ([1, 200] if args.quick else [1, 100, 1050])
    tmp = Path(tempfile.mkdtemp(prefix="bench_dryrun_"))
    rows = []
    try:
        for n in sizes:
            rows.append(bench_one(n, args.configfile, tmp))
            r = rows[-1]
            print(f"N={n}: {r['dryrun_s']:.2f} s, {r['jobs']} jobs, {r['peak_rss_mb']:.0f} MB", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    base = rows[0]
    for r in rows:
        r["time_ratio_vs_first"] = round(r["dryrun_s"] / base["dryrun_s"], 2)
        r["rss_ratio_vs_first"] = round(r["peak_rss_mb"] / base["peak_rss_mb"], 2)
        r["config"] = args.configfile or "config/config.yaml"
    csv_path = write_csv("bench_dryrun", rows)

    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.5))
    ns = [r["n_scenes"] for r in rows]
    ax[0].plot(ns, [r["dryrun_s"] for r in rows], "o-")
    ax[0].set(xlabel="scenes", ylabel="snakemake -n wall time (s)", xscale="log", yscale="log")
    ax[1].plot(ns, [r["peak_rss_mb"] for r in rows], "o-")
    ax[1].set(xlabel="scenes", ylabel="peak RSS of snakemake -n (MB)", xscale="log", ylim=(0, None))
    fig.suptitle(f"dry-run scaling ({rows[0]['config']})")
    png = save_plot(fig, "bench_dryrun", dpi=100)

    table = [f"{'scenes':>7} {'jobs':>7} {'dry-run s':>10} {'CPU s':>7} {'ms/scene':>9} {'peak RSS MB':>12} "
             f"{'x time':>7} {'x RSS':>6} {'gs2e scenes s':>14}"]
    for r in rows:
        table.append(f"{r['n_scenes']:>7} {r['jobs']:>7} {r['dryrun_s']:>10.2f} {r['dryrun_cpu_s']:>7.1f} "
                     f"{r['ms_per_scene']:>9.1f} "
                     f"{r['peak_rss_mb']:>12.0f} {r['time_ratio_vs_first']:>7.2f} "
                     f"{r['rss_ratio_vs_first']:>6.2f} {r['scenes_cli_s']:>14.2f}")
    last = rows[-1]
    report("\n".join(table),
           f"dry-run over {last['n_scenes']} scenes: {last['dryrun_s']:.1f} s, {last['dryrun_cpu_s']:.1f} CPU-s "
           f"({last['jobs']} jobs), "
           f"{last['ms_per_scene']:.1f} ms/scene, {last['time_ratio_vs_first']:.1f}x the 1-scene run's "
           f"{base['dryrun_s']:.1f} s; peak RSS {last['peak_rss_mb']:.0f} MB "
           f"({last['rss_ratio_vs_first']:.2f}x the 1-scene run's {base['peak_rss_mb']:.0f} MB)",
           [csv_path, png])
    return 0


if __name__ == "__main__":
    sys.exit(main())
