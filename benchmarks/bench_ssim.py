"""SSIM on the CPU: OpenCV blurs with a closed-form gradient against torch's
autograd through its depthwise convolutions (issue 44).

``gs2e.splat.loss.ssim`` (training's D-SSIM term and every benchmark score)
against ``ssim_reference`` (what it did until 2026-11-27, measured in the same
run): CPU ms of the value alone and of value + gradient, at the training sizes
of a DAVIS346 scene (349x260), a 646x482 view and 1280x720, in float32
(training) and float64 (scores); then one whole training step (render, loss,
backward, Adam) on trained real models of ../shared/data, the DAVIS346 cost
model's temple_ring and llff_fern at their training size, with each SSIM.

    python benchmarks/bench_ssim.py [--quick] [--reps 20]

``--quick``: 349x260 only and no training steps (seconds). Writes
benchmarks/results/bench_ssim.csv and .png; the last printed line is the
headline (the training step's CPU with torch's SSIM over with OpenCV's).
"""

from __future__ import annotations

import os
import sys

os.environ.setdefault("GS2E_PROGRESS", "0")

# first: importing gs2e sets OMP_WAIT_POLICY before torch loads
from gs2e.splat import loss as L  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

import harness  # noqa: E402
from harness import RESULTS  # noqa: E402

SIZES = ((349, 260), (646, 482), (1280, 720))
COST_RUNS = RESULTS / "cost_davis346" / "results"


def time_ssim(W: int, H: int, dtype, reps: int) -> list[dict]:
    g = torch.Generator().manual_seed(0)
    target = torch.rand(H, W, 3, generator=g, dtype=dtype)
    render = (target * 0.9 + 0.05 + 0.02 * torch.randn(H, W, 3, generator=g, dtype=dtype)).clamp(0, 1)
    rows = []
    for name, fn in (("torch autograd (before)", L.ssim_reference), ("OpenCV + closed form", L.ssim)):
        x = render.clone().requires_grad_(True)

        def both():
            fn(x, target).backward()
            x.grad = None

        with torch.no_grad():
            value_ms = harness.median_cpu_ms(lambda: fn(render, target), reps)
        rows.append({"part": f"ssim {W}x{H}", "dtype": str(dtype).replace("torch.", ""), "method": name,
                     "value_ms": value_ms, "value_and_grad_ms": harness.median_cpu_ms(both, reps), "gaussians": None})
    return rows


def time_training_step(scene: str, reps: int) -> list[dict]:
    """CPU ms of one training step at the cost model's training size, with
    each SSIM (the module attribute the loss calls is swapped)."""
    from gs2e.splat.strategy import PARAMS, Adam
    from gs2e.splat.train import train_step

    params, sh, cams, targets, (W, H), dtype = harness.cost_model_step_inputs(COST_RUNS / scene)
    bg = torch.zeros(3)
    rows, fast = [], L.ssim
    try:
        for name, fn in (("torch autograd (before)", L.ssim_reference), ("OpenCV + closed form", fast)):
            L.ssim = fn
            p = {k: v.clone() for k, v in params.items()}
            opt = Adam({k: 1e-4 for k in PARAMS})
            i = [0]

            def step():
                j = i[0] % len(cams)
                train_step(p, opt, cams[j], targets[j], bg, sh, "cpu", dtype, 0.2)
                i[0] += 1

            rows.append({"part": f"training step {scene} {W}x{H}", "dtype": dtype, "method": name,
                         "value_ms": float("nan"), "value_and_grad_ms": harness.median_cpu_ms(step, reps),
                         "gaussians": int(params["means"].shape[0])})
    finally:
        L.ssim = fast
    return rows


def plot(rows: list[dict]):
    plt = harness.pyplot()
    parts = list(dict.fromkeys(f"{r['part']} {r['dtype']}" for r in rows))
    fig, ax = plt.subplots(figsize=(10, 0.45 * len(parts) + 1.5))
    for k, (method, color) in enumerate((("torch autograd (before)", "tab:gray"), ("OpenCV + closed form", "tab:blue"))):
        v = [next(r["value_and_grad_ms"] for r in rows if f"{r['part']} {r['dtype']}" == p and r["method"] == method)
             for p in parts]
        ax.barh(np.arange(len(parts)) + 0.4 * k, v, height=0.4, color=color, label=method)
    ax.set_yticks(np.arange(len(parts)) + 0.2, parts, fontsize=8)
    ax.set_xscale("log")
    ax.set(xlabel="CPU ms (value + gradient; training step: whole step)", title="SSIM on the CPU")
    ax.legend(fontsize=8)
    return harness.save_plot(fig, "bench_ssim")


def main() -> int:
    ap = harness.parser(__doc__, quick="349x260 only, no training steps (seconds)")
    ap.add_argument("--reps", type=int, default=20)
    args = ap.parse_args()
    torch.set_num_threads(2)
    rows = []
    for W, H in SIZES[:1] if args.quick else SIZES:
        for dtype in (torch.float32, torch.float64):
            rows += time_ssim(W, H, dtype, args.reps)
    if not args.quick:
        for scene in ("temple_ring", "llff_fern"):
            if (COST_RUNS / scene / "splat" / "train_stats.json").is_file():
                rows += time_training_step(scene, args.reps)
            else:
                print(f"no trained model under {COST_RUNS / scene} (bench_cost_model.py --run {scene} "
                      "--sensor davis346 trains it): its training step is not measured")
    files = [harness.write_csv("bench_ssim" + ("_quick" if args.quick else ""), rows), plot(rows)]
    lines = [f"{'part':38s} {'dtype':8s} {'method':24s} {'value ms':>9s} {'+grad ms':>9s}"]
    for r in rows:
        lines.append(f"{r['part']:38s} {r['dtype']:8s} {r['method']:24s} {r['value_ms']:9.2f} "
                     f"{r['value_and_grad_ms']:9.2f}")
    steps = [r for r in rows if r["part"].startswith("training step")]
    if steps:
        pairs = {}
        for r in steps:
            pairs.setdefault(r["part"], {})[r["method"]] = r["value_and_grad_ms"]
        head = "headline: a training step with OpenCV's SSIM takes " + "; ".join(
            f"{v['OpenCV + closed form']:.0f} ms of CPU against {v['torch autograd (before)']:.0f} with torch's "
            f"({v['torch autograd (before)'] / v['OpenCV + closed form']:.2f}x, {part[len('training step '):]})"
            for part, v in pairs.items())
    else:
        r = {x["method"]: x for x in rows if x["part"] == "ssim 349x260" and x["dtype"] == "float32"}
        head = (f"headline: SSIM value + gradient at 349x260 float32 {r['OpenCV + closed form']['value_and_grad_ms']:.1f}"
                f" ms of CPU against {r['torch autograd (before)']['value_and_grad_ms']:.1f} with torch's")
    harness.report("\n".join(lines), head, files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
