"""Benchmark the optional CUDA backend (gsplat) against gs2e's CPU rasterizer.

On the trained models of bench_event_sampling.py (demo, temple_ring,
llff_fern; 2000 steps at 320 px, cached by that script's workflow), rendered at
their training size and at twice it, float32 like training: forward and
forward+backward per call with ``backend="cpu"`` and ``backend="gsplat"``
(gsplat returns CPU tensors, so the copies to and from the GPU are counted, as
the pipeline pays them), the agreement of the images (PSNR of the gsplat image
against the CPU one, largest difference) and of the gradients (cosine per
parameter). With ``--train-scene DIR`` (a posed scene, e.g. an SfM output),
the same short training run with each backend: held-out PSNR/SSIM, steps and
wall time. The CPU backend uses every core the machine has.

Needs a CUDA device and the gsplat package (``pip install -e .[cuda]``); says
why not and exits 0 otherwise. Usage:
    python benchmarks/bench_backend.py [--quick] [--train-scene DIR]
Writes benchmarks/results/bench_backend.csv (and bench_backend_train.csv) and
bench_backend.png; the last printed line is the headline.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

import harness
from harness import RESULTS
from train_runs import time_call, trained_cameras

KEYS = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


def trained_models(names: list[str], reps: int) -> list[dict]:
    """Forward and forward+backward per call (ms) with each backend on the
    trained models ``names`` (:func:`train_runs.trained_cameras`), and how
    far the gsplat images and gradients are from the CPU ones."""
    from gs2e.splat.model import render

    rows = []
    bg = torch.zeros(3)
    for name, p, info, cam in trained_cameras(names):
        out = {}
        for backend in ("cpu", "gsplat"):
            def once(backend=backend):
                return render(p, cam, bg, int(info["sh_degree"]), backend)
            with harness.clock() as first:
                once()  # warm-up: compiled kernels (gsplat builds its CUDA code on first use)
            if not rows:
                print(f"first {backend} call: {first.wall_s:.1f} s", flush=True)
            t, _ = time_call(once, p.values(), reps)  # seconds; the gradients land on
            t = {k.replace("_s", "_ms"): 1e3 * v for k, v in t.items()}  # the CPU: GPU waited for
            for x in p.values():
                x.grad = None
            img = once()[0]
            w = torch.linspace(-1, 1, img.numel()).reshape(img.shape)
            (img * w).sum().backward()
            out[backend] = (img.detach().double(), {k: p[k].grad.detach().double().flatten().clone()
                                                    for k in KEYS if p[k].grad is not None})
            rows.append(dict(scene=name, width=cam.width, height=cam.height,
                             gaussians=int(p["means"].shape[0]), backend=backend, **t))
        (ic, gc), (ig, gg) = out["cpu"], out["gsplat"]
        mse = float(((ic - ig) ** 2).mean())
        rows[-1]["psnr_vs_cpu_db"] = 10 * np.log10(1.0 / mse) if mse > 0 else float("inf")
        rows[-1]["max_abs_diff"] = float((ic - ig).abs().max())
        for k in (k for k in gc if float(gc[k].abs().sum()) > 0):  # sh_rest: 0 at degree 0
            rows[-1][f"grad_cos_{k}"] = float(torch.nn.functional.cosine_similarity(
                gc[k], gg[k], dim=0))
        rows[-1]["speedup_fwd_bwd"] = rows[-2]["fwd_bwd_min_ms"] / rows[-1]["fwd_bwd_min_ms"]
    return rows


def warm_gsplat() -> float:
    """Seconds of a first gsplat call in this process (it builds or loads its
    CUDA code: about 70 s for the build on an H100 machine, cached per machine)."""
    from gs2e.splat.rasterize import SplatCamera, rasterize

    with harness.clock() as t:
        one = dict(means=torch.tensor([[0.0, 0.0, 3.0]]), quats=torch.tensor([[1.0, 0.0, 0.0, 0.0]]),
                   log_scales=torch.full((1, 3), -2.0), opacity_logits=torch.zeros(1),
                   sh=torch.full((1, 1, 3), 0.5))
        rasterize(*one.values(), SplatCamera(np.eye(4), 20.0, 20.0, 16.0, 12.0, 32, 24),
                  backend="gsplat")
    return t.wall_s


def train_both(scene_dir: Path, iterations: int, work: Path) -> list[dict]:
    """The default recipe for ``iterations`` steps with each backend, same seed
    (gsplat's CUDA build is done before, not counted)."""
    from gs2e.splat.settings import SplatSettings
    from gs2e.splat.train import train

    print(f"first gsplat call of this process: {warm_gsplat():.1f} s", flush=True)
    rows = []
    for backend in ("cpu", "gsplat"):
        cfg = SplatSettings.defaults(backend=backend, max_iterations=iterations)
        with harness.clock() as t:
            st = train(scene_dir, work / f"model_{backend}", cfg, seed=0, resume=False)
        rows.append(dict(backend=backend, wall_s=t.wall_s,
                         **{k: st.get(k) for k in ("iterations", "stop_reason", "train_time_s",
                                                   "n_gaussians", "test_psnr", "test_ssim")}))
        print(f"[train {backend}] {json.dumps(rows[-1])}", flush=True)
    return rows


def plot(rows: list[dict]) -> Path:
    """Forward+backward per call with each backend, per model and size, as
    benchmarks/results/bench_backend.png; returns the path."""
    plt = harness.pyplot()
    labels = sorted({(r["scene"], r["width"], r["height"]) for r in rows},
                    key=lambda s: (s[0], s[1]))
    x = np.arange(len(labels))
    fig, ax = plt.subplots(figsize=(8, 4))
    for i, backend in enumerate(("cpu", "gsplat")):
        ms = [next(r["fwd_bwd_min_ms"] for r in rows if r["backend"] == backend
                   and (r["scene"], r["width"], r["height"]) == s) for s in labels]
        ax.bar(x + (i - 0.5) * 0.4, ms, 0.4, label=backend)
    ax.set_xticks(x, [f"{s[0]}\n{s[1]}x{s[2]}" for s in labels], fontsize=8)
    ax.set_yscale("log")
    ax.set_ylabel("forward+backward per call (ms, min)")
    ax.legend()
    return harness.save_plot(fig, "bench_backend", dpi=110)


def main() -> int:
    ap = harness.parser(__doc__, quick="demo only, fewer repetitions (without CUDA and gsplat: says why "
                        "and stops at once)")
    ap.add_argument("--models", default="demo,temple_ring,llff_fern",
                    help="trained models to time ('' = none, e.g. with --train-scene alone)")
    ap.add_argument("--train-scene", type=Path, help="a posed scene folder to train on")
    ap.add_argument("--train-iterations", type=int, default=1500)
    ap.add_argument("--work", type=Path, default=RESULTS / "work_backend")
    a = ap.parse_args()
    from gs2e.splat.backend import gsplat_status

    ok, why = gsplat_status()
    if not ok:
        harness.report(None, f"HEADLINE: gsplat backend not measured: {why}")
        return 0
    print(f"gsplat: {why}; torch {torch.__version__}; CPU threads {torch.get_num_threads()}",
          flush=True)
    import pandas as pd

    names = ["demo"] if a.quick else [n for n in a.models.split(",") if n]
    rows = trained_models(names, 3 if a.quick else 7) if names else []
    files = []
    if rows:
        # cpu rows lack the comparison columns
        files += [harness.write_csv("bench_backend", pd.DataFrame(rows)), plot(rows)]
    for r in rows:
        extra = "" if r["backend"] == "cpu" else (
            f"  x{r['speedup_fwd_bwd']:.1f} vs cpu, image PSNR vs cpu {r['psnr_vs_cpu_db']:.1f} dB,"
            f" max |diff| {r['max_abs_diff']:.2e}, grad cos "
            + " ".join(f"{k[9:]} {v:.4f}" for k, v in r.items() if k.startswith("grad_cos_")))
        print(f"{r['scene']:12s} {r['width']}x{r['height']} {r['backend']:7s} fwd {r['fwd_min_ms']:8.2f}"
              f" ms  fwd+bwd {r['fwd_bwd_min_ms']:8.2f} ms{extra}")
    train = train_both(a.train_scene, a.train_iterations, a.work) if a.train_scene else []
    if train:
        files.append(harness.write_csv("bench_backend_train", pd.DataFrame(train)))
    g = [r for r in rows if r["backend"] == "gsplat"]
    parts = [f"gsplat fwd+bwd {min(r['speedup_fwd_bwd'] for r in g):.1f}-"
             f"{max(r['speedup_fwd_bwd'] for r in g):.1f}x faster than the CPU backend "
             f"({torch.get_num_threads()} threads) on {len(g)} trained model/size pairs, images "
             f"{min(r['psnr_vs_cpu_db'] for r in g):.1f} dB or closer to the CPU ones"] if g else []
    if train:
        c, gs = train
        parts.append(f"training {a.train_iterations} steps: cpu {c['test_psnr']:.2f} dB in "
                     f"{c['wall_s']:.0f} s, gsplat {gs['test_psnr']:.2f} dB in {gs['wall_s']:.0f} s")
    harness.report(None, "HEADLINE: " + ("; ".join(parts) or "nothing measured"), files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
