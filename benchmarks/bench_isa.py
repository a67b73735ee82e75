"""The CPU kernels on two instruction sets in one run, against a baseline revision (issue 44).

For each target a worker process with its own numba cache compiles and times,
on trained models (the demo, temple_ring and llff_fern of
``bench_event_sampling.py``, built and cached by that script's workflow; real
photos from ../shared/data, 320 px):

* ``fwd_f32``: the forward compositing kernel in float32 (event and render stages);
* ``fwd_f64`` / ``bwd_f64``: the float64 forward and backward of a training step
  (and ``fwd_f32g`` / ``bwd_f32``, the float32 training passes);
* ``project``, ``bin``: projection of every Gaussian and the depth-sorted tile lists;
* ``event_sample``: one whole event sample (project, bin, composite, luminance);
* ``train_step``: one whole training step (render, 0.8 L1 + 0.2 D-SSIM,
  autograd, the hand-written backward, Adam) at full size in float64;
  ``train_step_f32`` the same in float32, and ``train_step_auto`` in what
  ``splat.compute_dtype: auto`` (the default) takes at this size;
* ``ssim_f64``: SSIM of a frame in float64, as the benchmark tasks score frames;
* and all of it again with the gs2e of ``--baseline-rev`` (a git worktree,
  its own workers and caches; a worker imports the gs2e of the checkout on
  its ``PYTHONPATH`` and stops if it got another) on the same inputs:
  today's speed-up.

Targets: ``host`` (numba's and torch's own choice for this CPU) and ``avx2``
(numba generating code for Haswell, ``NUMBA_CPU_NAME=haswell``: AVX2 + FMA, no
AVX-512, and torch's ``ATEN_CPU_CAPABILITY=avx2``). On a host without AVX-512
both are the same code, so only ``host`` runs (reported as the AVX2 figure).
Per row: CPU ms per call (the process's CPU time, both threads: the work a
call costs, steadier than wall time on a shared machine), median of ``--reps``
calls per worker and then over ``--rounds`` rounds, in which every worker
(today and the baseline on each target) runs once, in turned order, so that
a drift of the machine falls on all; ns per pixel and per (tile, Gaussian)
pair, the avx2 / host ratio (throughput of AVX2 code as a fraction of the
host's) and the baseline / today ratio.

    python benchmarks/bench_isa.py [--quick] [--scenes demo,temple_ring,llff_fern]
        [--targets host,avx2] [--baseline-rev 783ff0e] [--rounds 2]

Writes benchmarks/results/bench_isa.csv and bench_isa.png; the last printed
line is the headline.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

import harness  # noqa: E402
from harness import REPO, median_cpu_ms  # noqa: E402

BASELINE_REV = "783ff0e"  # main when issue 44 was filed


def host_flags() -> list[str]:
    """The vector extensions of this CPU that matter here."""
    flags = harness.cpu_flags()
    return [f for f in ("sse4_2", "avx", "avx2", "fma", "avx512f", "avx512vl", "avx512bw") if f in flags]


# ------------------------------------------------------------------ worker
def worker(scenes: dict[str, str], reps: int, root: str) -> list[dict]:
    """Time every part on every scene in this process (its target is its
    environment, the gs2e it runs the one of checkout ``root``, first on its
    ``PYTHONPATH``); rows as dicts."""
    import numba
    import torch

    from gs2e.events.sampling import image_luminance
    from gs2e.splat import raster as R
    from gs2e.splat.forward import ForwardRenderer
    from gs2e.splat.model import load_model, render
    from gs2e.splat.rasterize import TILE, SplatCamera
    from gs2e.splat.loss import ssim
    from gs2e.splat.strategy import PARAMS, Adam
    from gs2e.trajectory import load_trajectory

    try:  # what `gs2e train` computes in by default (compute_dtype auto) at a training size
        from gs2e.splat.optimise import training_dtype
    except ImportError:  # a baseline from before the rule moved there
        from gs2e.splat.train import training_dtype

    train_step = harness.train_step_function()

    harness.check_gs2e_root(root)
    numba.set_num_threads(2)
    torch.set_num_threads(2)
    rows = []
    for name, d in scenes.items():
        d = Path(d)
        traj = load_trajectory(d / "trajectories" / "base_medium.npz")
        params, info = load_model(d / "splat")
        K = np.asarray(traj.K, np.float64)
        W, H = int(traj.width), int(traj.height)
        c2w = traj.pose_at(np.array([float(traj.t_us[len(traj.t_us) // 2])]))[0]
        fr = ForwardRenderer(params, int(info["sh_degree"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H)
        fr.render(c2w)  # projects every Gaussian: the inputs below
        offsets, gids = R.bin_gaussians(fr.means2d, fr.depths, fr.radii, W, H, TILE, fr.opac)
        n_pairs, n_px = int(gids.shape[0]), W * H
        tiles = np.arange(fr.n_tiles, dtype=np.int64)
        sched = R.tile_schedule(offsets)
        feats4 = np.concatenate([fr.colors.astype(np.float64), fr.depths[:, None]], 1)

        def row(part, ms):
            rows.append({"scene": name, "part": part, "width": W, "height": H,
                         "gaussians": fr.n_gaussians, "pairs": n_pairs, "ms": ms,
                         "ns_per_px": 1e6 * ms / n_px, "ns_per_pair": 1e6 * ms / max(1, n_pairs)})

        for dt, part in ((np.float32, "fwd_f32"), (np.float64, "fwd_f64")):
            m2, cn, op, ft = (fr.means2d.astype(dt), fr.conics.astype(dt), fr.opac.astype(dt),
                              (fr.colors if dt == np.float32 else feats4).astype(dt))
            bg = np.zeros(ft.shape[1], dt)
            out = np.empty((H, W, ft.shape[1]), dt)
            T = np.empty((H, W), dt)
            nc = np.empty((H, W), np.int32)

            def fwd(kern):
                return lambda: kern(tiles, offsets, gids, m2, cn, op, ft, bg, W, H, TILE, out, T, nc,
                                    *sched)

            row(part, median_cpu_ms(fwd(R.forward_kernel(dt, offsets)), reps))
            if dt == np.float64:
                rng = np.random.default_rng(0)
                g_out = rng.standard_normal(out.shape)
                g_T = rng.standard_normal(T.shape)
                for cdt, bpart in ((np.float64, "bwd_f64"), (np.float32, "bwd_f32")):
                    ftc = ft.astype(cdt)
                    m2c, cnc, opc = m2.astype(cdt), cn.astype(cdt), op.astype(cdt)
                    _, T2, nc2 = R.rasterize_forward(m2c, cnc, opc, ftc, np.zeros(4, cdt), W, H, offsets,
                                                      gids, TILE, compute_dtype=cdt)
                    if cdt == np.float32:
                        row("fwd_f32g", median_cpu_ms(lambda: R.rasterize_forward(
                            m2c, cnc, opc, ftc, np.zeros(4, cdt), W, H, offsets, gids, TILE,
                            compute_dtype=cdt), reps))

                    row(bpart, median_cpu_ms(lambda: R.rasterize_backward(
                        m2c, cnc, opc, ftc, W, H, offsets, gids, T2, nc2, g_out, g_T, TILE,
                        compute_dtype=cdt), reps))
        vm = fr._viewmat(c2w)
        row("project", median_cpu_ms(lambda: fr._project(vm, None), reps))
        row("bin", median_cpu_ms(lambda: R.bin_gaussians(fr.means2d, fr.depths, fr.radii, W, H, TILE,
                                                      fr.opac), reps))
        lum = np.empty((H, W), np.float32)
        row("event_sample", median_cpu_ms(lambda: image_luminance(fr.render(c2w), lum), reps))

        # one training step as gs2e train runs it at full size (float64 passes)
        p = {k: v.clone() for k, v in params.items()}
        cam = SplatCamera.from_c2w(c2w, K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H)
        bg3 = torch.zeros(3)
        with torch.no_grad():
            target = render(p, cam, bg3, int(info["sh_degree"]), "cpu")[0].clone()
        target = (target * 0.9 + 0.05).contiguous()  # a photo the model does not reproduce
        for part, dtype in (("train_step", "float64"), ("train_step_f32", "float32"),
                            ("train_step_auto", training_dtype("auto", (W, H)))):
            opt = Adam({k: 1e-4 for k in PARAMS})
            row(part, median_cpu_ms(lambda: train_step(p, opt, cam, target, bg3, int(info["sh_degree"]),
                                                   "cpu", dtype, 0.2), reps))
        # a frame's SSIM in float64, as the benchmark tasks score every method's frame
        a64, b64 = target.double(), (target * 0.8 + 0.1).double()
        row("ssim_f64", median_cpu_ms(lambda: ssim(a64, b64), reps))
    return rows


def run_target(target: str, scenes: dict[str, Path], reps: int, root: Path = REPO,
               caches: dict[str, Path] | None = None) -> list[dict]:
    """A worker for ``target`` in a fresh process with its own numba cache
    (``caches[target]``, made on first use: later rounds load the kernels
    compiled by the first), running the gs2e of ``root`` (this checkout, or
    the baseline's)."""
    caches = {} if caches is None else caches
    cache = caches.setdefault(target, Path(tempfile.mkdtemp(prefix=f"bench_isa_{target}_")))
    env = harness.gs2e_env(root, NUMBA_CACHE_DIR=str(cache), **harness.ISA_TARGET_ENV[target.split("-")[0]])
    cmd = [sys.executable, __file__, "--worker", json.dumps({k: str(v) for k, v in scenes.items()}),
           "--reps", str(reps), "--root", str(root)]
    with harness.clock() as t:
        res = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=root)
    if res.returncode != 0:
        raise SystemExit(f"worker {target} failed:\n{res.stderr[-3000:]}")
    rows = json.loads(res.stdout.strip().splitlines()[-1])
    print(f"  {target}: {len(rows)} timings in {t.wall_s:.0f} s (compiles included)", flush=True)
    return [{"target": target, **r} for r in rows]


def _median_over_rounds(raw: list[dict]) -> tuple[list[dict], list[dict]]:
    """One row per (target, scene, part): the median over rounds of the
    workers' medians; today's rows and the baseline's."""
    groups: dict[tuple, list[dict]] = {}
    for r in raw:
        groups.setdefault((r["target"], r["scene"], r["part"]), []).append(r)
    rows = []
    for g in groups.values():
        row = {k: v for k, v in g[0].items() if k != "round"}
        ms = float(np.median([r["ms"] for r in g]))
        scale = ms / g[0]["ms"]
        row.update(ms=ms, ns_per_px=g[0]["ns_per_px"] * scale, ns_per_pair=g[0]["ns_per_pair"] * scale,
                   rounds=len(g), ms_spread=float(max(r["ms"] for r in g) / min(r["ms"] for r in g)))
        rows.append(row)
    return ([r for r in rows if "-baseline" not in r["target"]],
            [r for r in rows if "-baseline" in r["target"]])


def plot(rows: list[dict], targets: list[str]) -> Path:
    """ms per call per part and scene, today on each target and the baseline on
    the first, as benchmarks/results/bench_isa.png; returns the path."""
    plt = harness.pyplot()
    parts = list(dict.fromkeys(r["part"] for r in rows))
    scenes = list(dict.fromkeys(r["scene"] for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(4.2 * len(scenes), 3.8), squeeze=False)
    for ax, sc in zip(axes[0], scenes):
        x = np.arange(len(parts))
        w = 0.8 / (len(targets) + 1)
        for i, tg in enumerate(targets):
            ms = [next((r["ms"] for r in rows if r["scene"] == sc and r["part"] == p and r["target"] == tg),
                       np.nan) for p in parts]
            ax.bar(x + i * w, ms, w, label=f"today, {tg}")
        bms = [next((r["baseline_ms"] or np.nan for r in rows if r["scene"] == sc and r["part"] == p
                     and r["target"] == targets[0]), np.nan) for p in parts]
        ax.bar(x + len(targets) * w, bms, w, label=f"baseline, {targets[0]}", color="0.6")
        ax.set_xticks(x + 0.4 - w / 2, parts, rotation=60, ha="right")
        ax.set(ylabel="CPU ms per call (2 threads)", title=sc, yscale="log")
    axes[0][0].legend(fontsize=8)
    return harness.save_plot(fig, "bench_isa", dpi=110)


def main() -> int:
    ap = harness.parser(__doc__, quick="the demo only, 3 repetitions (a few minutes: every worker compiles)",
                        baseline_rev=BASELINE_REV)
    ap.add_argument("--scenes", default="demo,temple_ring,llff_fern")
    ap.add_argument("--targets", default=None, help="host,avx2 (default: both where the host has AVX-512)")
    ap.add_argument("--reps", type=int, default=9)
    ap.add_argument("--rounds", type=int, default=2,
                    help="times every worker runs, sides alternating (medians over rounds)")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--root", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:  # the gs2e to time, this checkout's or the baseline's, is on PYTHONPATH
        print(json.dumps(worker(json.loads(args.worker), args.reps, args.root)))
        return 0
    from event_runs import build_scenes

    flags = host_flags()
    avx512 = "avx512f" in flags
    targets = harness.isa_targets(args.targets)
    names = ["demo"] if args.quick else args.scenes.split(",")
    reps = 3 if args.quick else args.reps
    print(f"host: {os.cpu_count()} CPUs, flags {' '.join(flags)}; targets {', '.join(targets)}"
          + ("" if avx512 else " (no AVX-512 here: host code is AVX2 code)"), flush=True)
    scenes = build_scenes(names)
    rounds = 1 if args.quick else args.rounds
    caches: dict[str, Path] = {}
    raw: list[dict] = []
    with harness.baseline_checkout(args.baseline_rev) as checkout:
        runs = [(t, REPO) for t in targets] + [(f"{t}-baseline", checkout) for t in targets]
        for k in range(rounds):  # every side once per round, in turned order: drift falls on all
            order = runs if k % 2 == 0 else runs[::-1]
            raw += [dict(r, round=k) for t, root in order for r in run_target(t, scenes, reps, root, caches)]
    rows, base_rows = _median_over_rounds(raw)
    base = {(r["scene"], r["part"], r["target"].split("-")[0]): r["ms"] for r in base_rows}
    host = {(r["scene"], r["part"]): r for r in rows if r["target"] == "host"}
    for r in rows:
        r["isa"] = ("avx512" if avx512 else "avx2") if r["target"] == "host" else "avx2"
        h = host.get((r["scene"], r["part"]))
        r["avx2_throughput_vs_host"] = (h["ms"] / r["ms"]) if r["target"] == "avx2" and h else None
        r["baseline_ms"] = base.get((r["scene"], r["part"], r["target"]))
        r["speedup_vs_baseline"] = (r["baseline_ms"] / r["ms"]) if r["baseline_ms"] else None
    files = [harness.write_csv("bench_isa", rows), plot(rows, targets)]
    table = [f"\n{'scene':12s} {'part':15s} {'target':6s} {'ms':>8s} {'ns/px':>8s} {'ns/pair':>8s} "
             f"{'avx2/host':>9s} {'vs ' + args.baseline_rev:>10s}"]
    for r in rows:
        a = r["avx2_throughput_vs_host"]
        s = r["speedup_vs_baseline"]
        table.append(f"{r['scene']:12s} {r['part']:15s} {r['target']:6s} {r['ms']:8.2f} {r['ns_per_px']:8.1f} "
                     f"{r['ns_per_pair']:8.1f} {'-' if a is None else f'{a:.2f}':>9s} "
                     f"{'-' if s is None else f'{s:.2f}x':>10s}")
    t0 = targets[0]
    sp = {p: [r["speedup_vs_baseline"] for r in rows if r["part"] == p and r["target"] == t0
              and r["speedup_vs_baseline"]] for p in ("fwd_f32", "bwd_f64", "event_sample", "train_step", "train_step_auto", "ssim_f64")}
    isa = "AVX-512" if (avx512 and t0 == "host") else "AVX2"
    line = ", ".join(f"{p} {min(v):.2f}-{max(v):.2f}x" for p, v in sp.items() if v)
    extra = ""
    if "avx2" in targets and "host" in targets:
        fr = [r["avx2_throughput_vs_host"] for r in rows if r["avx2_throughput_vs_host"]]
        extra = f"; AVX2 code at {min(fr):.2f}-{max(fr):.2f} of the host's throughput"
    harness.report("\n".join(table),
                   f"headline ({isa}, {len(names)} scene(s)): today against {args.baseline_rev}: {line}{extra}",
                   files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
