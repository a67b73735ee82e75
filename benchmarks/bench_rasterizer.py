"""Benchmark the CPU Gaussian-splatting rasterizer (gs2e.splat).

Times forward and forward+backward of :func:`gs2e.splat.rasterize.rasterize`
at 256x256 / 50k Gaussians and 512x384 / 200k (float32, random Gaussians in
front of the camera, a few pixels wide), and in the same run the dense
pure-torch reference on the largest scene it can hold, on which both are
timed for the speed ratio. It also times the compositing kernel alone against
the pixel-major algorithm compiled from C with gcc -O3 -fopenmp.

Trained models (the yardstick that matters: larger, overlapping Gaussians):
the demo, temple_ring and llff_fern models of bench_event_sampling.py
(trained 2000 steps at 320 px; built and cached by that script's workflow),
rendered at their training size and at twice it (640 px), float32 like
training: forward and forward+backward with today's kernels and with the
baseline pixel-major kernels (benchmarks/raster_v0.py, the kernels before
the SIMD rewrite, which split tiles over threads in contiguous blocks),
swapped in within the same run; projection, SH and binning are today's for
both. The images and gradients of both are compared.

Usage: python benchmarks/bench_rasterizer.py [--quick]
Writes benchmarks/results/bench_rasterizer.csv and .png; the last printed line
is the headline.
"""

from __future__ import annotations

import os

# before numpy/torch/numba load OpenMP: no spin-waiting on a shared machine
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import ctypes
import resource
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

import harness
from gs2e.splat import raster as R
from gs2e.splat.rasterize import SplatCamera, rasterize
from gs2e.splat.reference import render_reference
from train_runs import time_call, trained_cameras

HERE = Path(__file__).resolve().parent
KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh")


def make_scene(n, width, height, seed=0, dtype=torch.float32):
    """Random Gaussians in the view frustum at depth 2-6, pixel sigma ~1.5 px
    (log-normal), random orientation and opacity, SH degree 3."""
    rng = np.random.default_rng(seed)
    fx = 0.8 * width
    z = rng.uniform(2.0, 6.0, n)
    u = rng.uniform(-0.05 * width, 1.05 * width, n)
    v = rng.uniform(-0.05 * height, 1.05 * height, n)
    sig_px = np.exp(rng.normal(np.log(1.5), 0.5, (n, 3)))
    sh = rng.normal(0.0, 0.2, (n, 16, 3))
    sh[:, 0] = rng.normal(0.0, 1.0, (n, 3))
    p = dict(means=np.stack([(u - width / 2) / fx * z, (v - height / 2) / fx * z, z], 1),
             quats=rng.normal(size=(n, 4)), log_scales=np.log(sig_px * z[:, None] / fx),
             opacity_logits=rng.normal(0.0, 2.0, n), sh=sh, background=np.zeros(3))
    p = {k: torch.tensor(a, dtype=dtype, requires_grad=True) for k, a in p.items()}
    cam = SplatCamera(np.eye(4), fx, fx, width / 2, height / 2, width, height)
    return p, cam


def time_render(fn, p, cam, reps):
    """Wall seconds of forward and forward+backward (loss = sum of outputs):
    dict of median and min over ``reps``, plus median process CPU seconds
    (:func:`train_runs.time_call`)."""
    return time_call(lambda: fn(*(p[k] for k in KEYS), cam, p["background"]), p.values(), reps)


def c_vs_numba(reps, quick):
    """Compositing kernel: numba vs the same loop compiled from C (OpenMP)."""
    gcc = shutil.which("gcc")
    if gcc is None:
        return None
    p, cam = make_scene(50_000, 256, 256)
    with torch.no_grad():
        _, _, _, meta = rasterize(*(p[k] for k in KEYS), cam, p["background"])
    m2 = meta["means2d"].numpy()
    off, gids = R.bin_gaussians(m2, meta["depths"].numpy(), meta["radii"].numpy(), 256, 256)
    rng = np.random.default_rng(1)
    n = m2.shape[0]
    m2f = np.ascontiguousarray(m2, dtype=np.float32)
    con = np.ascontiguousarray(meta["conics"].numpy(), dtype=np.float32)
    op = torch.sigmoid(p["opacity_logits"]).detach().numpy().astype(np.float32)
    feats = rng.uniform(0, 1, (n, 4)).astype(np.float32)
    bg = np.zeros(4, np.float32)
    tmp = Path(tempfile.mkdtemp())
    so = tmp / "raster_fwd_c.so"
    with harness.clock() as build:
        subprocess.run([gcc, "-O3", "-march=native", "-fopenmp", "-shared", "-fPIC",
                        str(HERE / "raster_fwd_c.c"), "-o", str(so), "-lm"], check=True)
    lib = ctypes.CDLL(str(so))
    ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)  # noqa: E731
    out_c = np.empty((256, 256, 4), np.float32)
    T_c = np.empty((256, 256), np.float32)
    nc_c = np.empty((256, 256), np.int32)
    lib.raster_fwd.restype = None
    args = [ptr(off), ptr(gids), ptr(m2f), ptr(con), ptr(op), ptr(feats), ctypes.c_int(4),
            ptr(bg), ctypes.c_int(256), ctypes.c_int(256), ctypes.c_int(16),
            ptr(out_c), ptr(T_c), ptr(nc_c)]
    t_c, t_nb = [], []
    for _ in range(reps):
        with harness.clock() as t:
            lib.raster_fwd(*args)
        t_c.append(t.wall_s)
        with harness.clock() as t:
            out_n, T_n, nc_n = R.rasterize_forward(m2f, con, op, feats, bg, 256, 256, off, gids)
        t_nb.append(t.wall_s)
    shutil.rmtree(tmp, ignore_errors=True)
    return dict(numba_s=float(np.median(t_nb)), c_s=float(np.median(t_c)), c_build_s=build.wall_s,
                numba_min_s=float(np.min(t_nb)), c_min_s=float(np.min(t_c)),
                max_abs_diff=float(np.abs(out_c - out_n).max()),
                same_ncontrib=bool(np.array_equal(nc_c, nc_n)))


def trained_models(reps: int, quick: bool) -> list[dict]:
    """fwd and fwd+bwd on trained models (:func:`train_runs.trained_cameras`),
    today's kernels vs the baseline."""
    import raster_v0 as v0
    from gs2e.splat.model import render

    def v0_forward(*args):  # the baseline splits tiles by prange's contiguous blocks
        return v0.raster_forward_kernel(*args[:-2])

    def v0_backward(*args):
        return v0.raster_backward_kernel(*args[:-2])

    kernels = {"simd": (R.raster_forward_kernel, R.raster_backward_kernel),
               "pixel-major (baseline)": (v0_forward, v0_backward)}
    rows = []
    bg = torch.zeros(3)
    names = ["demo"] if quick else ["demo", "temple_ring", "llff_fern"]
    for name, p, info, cam in trained_cameras(names):
        outs = {}
        for impl, (fwd, bwd) in kernels.items():
            R.raster_forward_kernel, R.raster_backward_kernel = fwd, bwd
            try:
                t, meta = time_call(lambda: render(p, cam, bg, int(info["sh_degree"])),
                                    p.values(), reps)
                img = render(p, cam, bg, int(info["sh_degree"]))[0]
                g = torch.autograd.grad(img.sum(), [p["means"], p["opacity_logits"]])
                outs[impl] = (img.detach(), *g)
            finally:
                R.raster_forward_kernel, R.raster_backward_kernel = kernels["simd"]
            rows.append(dict(scene=f"{name} trained {cam.width}x{cam.height}", width=cam.width,
                             height=cam.height, n=int(p["means"].shape[0]), backend=impl, **t,
                             n_pairs=meta["n_pairs"]))
        a, b = outs["simd"], outs["pixel-major (baseline)"]
        rows[-2]["max_abs_img_diff"] = float((a[0] - b[0]).abs().max())
        rows[-2]["grad_rel_diff"] = max(float((x - y).abs().max() / y.abs().max().clamp_min(1e-30))
                                        for x, y in zip(a[1:], b[1:]))
    return rows


def main(argv=None):
    ap = harness.parser(__doc__, quick="fewer repetitions (< 60 s)")
    ap.add_argument("--out", default=str(harness.RESULTS), help="output folder")
    args = ap.parse_args(argv)
    reps = 3 if args.quick else 7
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    import numba
    threads = numba.get_num_threads()
    print(f"cores: {os.cpu_count()}, numba threads: {threads}, torch threads: {torch.get_num_threads()}, "
          f"OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}")

    # warm-up: compile or load the numba cache
    with harness.clock() as warm:
        p, cam = make_scene(100, 32, 32)
        time_render(rasterize, p, cam, 1)
    t_warm = warm.wall_s

    rows = []
    for (w, h, n) in [(256, 256, 50_000), (512, 384, 200_000)]:
        p, cam = make_scene(n, w, h)
        t, meta = time_render(rasterize, p, cam, reps)
        rows.append(dict(scene=f"{w}x{h}/{n // 1000}k", width=w, height=h, n=n, backend="gs2e-numba",
                         **t, n_pairs=meta["n_pairs"]))

    # the dense reference: the largest scene it holds in reasonable time/memory
    # 128x128/2000 needs ~3 GB of autograd buffers: the largest we allow
    # ourselves on a machine shared with other jobs
    dense = [(64, 64, 1000), (128, 128, 2000)]
    ratio = {}
    for (w, h, n) in dense:
        p, cam = make_scene(n, w, h, seed=2)
        td, _ = time_render(render_reference, p, cam, 1 if args.quick else 3)
        t, meta = time_render(rasterize, p, cam, 3 * reps)
        sc = f"{w}x{h}/{n}"
        rows.append(dict(scene=sc, width=w, height=h, n=n, backend="dense-torch",
                         **td, n_pairs=w * h * n))
        rows.append(dict(scene=sc, width=w, height=h, n=n, backend="gs2e-numba",
                         **t, n_pairs=meta["n_pairs"]))
        ratio[sc] = (td["fwd_bwd_s"] / t["fwd_bwd_s"], td["fwd_bwd_min_s"] / t["fwd_bwd_min_s"])
        dense_ns = td["fwd_bwd_min_s"] / (w * h * n) * 1e9
        dense_pairs = w * h * n
    peak_gb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # kB -> GB

    trained = trained_models(reps, args.quick)
    rows += trained

    cmp = c_vs_numba(reps if args.quick else 9, args.quick)
    if cmp is not None:
        rows.append(dict(scene="256x256/50k composite-fwd-kernel", width=256, height=256, n=50_000,
                         backend="numba-kernel", fwd_s=cmp["numba_s"], fwd_min_s=cmp["numba_min_s"],
                         n_pairs=0))
        rows.append(dict(scene="256x256/50k composite-fwd-kernel", width=256, height=256, n=50_000,
                         backend="c-openmp-kernel", fwd_s=cmp["c_s"], fwd_min_s=cmp["c_min_s"],
                         n_pairs=0))

    import pandas as pd
    df = pd.DataFrame(rows)
    df["threads"] = threads
    with pd.option_context("display.width", 140, "display.max_columns", 20):
        print(df.to_string(index=False, float_format=lambda x: f"{x:.4f}"))
    print(f"numba warm-up (compile or cache load): {t_warm:.1f} s")
    if cmp is not None:
        print(f"compositing kernel 256x256/50k (median/min): numba {cmp['numba_s'] * 1e3:.1f}/"
              f"{cmp['numba_min_s'] * 1e3:.1f} ms, C -O3 -fopenmp {cmp['c_s'] * 1e3:.1f}/"
              f"{cmp['c_min_s'] * 1e3:.1f} ms (min ratio C/numba {cmp['c_min_s'] / cmp['numba_min_s']:.2f}, "
              f"gcc build {cmp['c_build_s']:.1f} s, max |diff| {cmp['max_abs_diff']:.1e}, "
              f"same stop indices: {cmp['same_ncontrib']})")
    print(f"peak resident memory of this run: {peak_gb:.1f} GB (dense reference buffers)")
    big_pairs = rows[0]["width"] * rows[0]["height"] * rows[0]["n"]
    extra = big_pairs * dense_ns * 1e-9
    print(f"dense reference extrapolated to 256x256/50k ({dense_ns:.0f} ns per pixel-Gaussian "
          f"pair, ~{peak_gb * big_pairs / dense_pairs:.0f} GB would be needed): {extra:.0f} s, i.e. "
          f"{extra / rows[0]['fwd_bwd_min_s']:.0f}x slower (extrapolated, not measured)")
    for sc, (r_med, r_min) in ratio.items():
        print(f"dense torch reference {sc}: {r_med:.0f}x (median) / {r_min:.0f}x (min) slower "
              "than gs2e, forward+backward")
    speedups = []
    for i in range(0, len(trained), 2):
        a, b = trained[i], trained[i + 1]
        speedups.append((a["scene"], b["fwd_min_s"] / a["fwd_min_s"], b["fwd_bwd_min_s"] / a["fwd_bwd_min_s"]))
        print(f"{a['scene']} ({a['n']} Gaussians): forward {b['fwd_min_s'] * 1e3:.1f} -> "
              f"{a['fwd_min_s'] * 1e3:.1f} ms ({speedups[-1][1]:.2f}x), forward+backward "
              f"{b['fwd_bwd_min_s'] * 1e3:.1f} -> {a['fwd_bwd_min_s'] * 1e3:.1f} ms "
              f"({speedups[-1][2]:.2f}x) vs the pixel-major baseline (min of {reps}); "
              f"max |image diff| {a['max_abs_img_diff']:.1e}, gradient rel. diff {a['grad_rel_diff']:.1e}")
    print(f"load average during the run: {os.getloadavg()} (shared machine: min is the "
          "least-disturbed repetition)")

    plt = harness.pyplot()
    fig, ax = plt.subplots(figsize=(12, 4.5))
    sub = df[df.backend.isin(["gs2e-numba", "dense-torch", "simd", "pixel-major (baseline)"])]
    labels = [f"{r.scene}\n{r.backend}" for r in sub.itertuples()]
    x = np.arange(len(sub))
    ax.bar(x - 0.2, sub.fwd_s, 0.4, label="forward")
    ax.bar(x + 0.2, sub.fwd_bwd_s, 0.4, label="forward+backward")
    ax.set_yscale("log")
    ax.set_xticks(x, labels, fontsize=6, rotation=60, ha="right")
    ax.set_ylabel("seconds (median)")
    ax.axhline(0.5, color="k", ls=":", lw=1, label="target 0.5 s (256x256/50k)")
    ax.set_title(f"gs2e CPU rasterizer, {threads} threads")
    ax.legend(fontsize=8)
    if out_dir == harness.RESULTS.resolve():
        files = [harness.write_csv("bench_rasterizer", df), harness.save_plot(fig, "bench_rasterizer")]
    else:  # --out: the same files in another folder
        files = [out_dir / "bench_rasterizer.csv", out_dir / "bench_rasterizer.png"]
        df.to_csv(files[0], index=False)
        fig.tight_layout()
        fig.savefig(files[1], dpi=120)

    r0, r1 = rows[0], rows[1]
    big = list(ratio)[-1]
    fb = [sp[2] for sp in speedups]
    harness.report(None, f"HEADLINE: trained models, forward+backward {min(fb):.2f}-{max(fb):.2f}x faster than "
                   f"the pixel-major baseline (forward {min(sp[1] for sp in speedups):.2f}-"
                   f"{max(sp[1] for sp in speedups):.2f}x) over {len(speedups)} scene/size pairs; "
                   f"random 256x256/50k {r0['fwd_bwd_min_s']:.3f} s min / "
                   f"{r0['fwd_bwd_s']:.3f} s median (target <= 0.5), 512x384/200k {r1['fwd_bwd_min_s']:.3f} / "
                   f"{r1['fwd_bwd_s']:.3f} s, {ratio[big][1]:.0f}x (min) / {ratio[big][0]:.0f}x (median) faster "
                   f"than the dense torch reference ({big}), {threads} threads", files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
