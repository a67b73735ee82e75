"""Training scenes and render timings that several benchmarks share, so that
no script imports another: the scenes bench_train.py and
bench_train_budget.py train on (cached in a work folder), and the forward /
forward+backward timing of a render on the trained models of
bench_event_sampling.py, which bench_rasterizer.py and bench_backend.py run.

gs2e is imported inside the functions, so that a script's ``--help`` does not
load the kernels.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from harness import REPO, clock, gs2e_env

# photo folders of the real scenes under ../shared/data
PHOTOS = {"temple_ring": "temple_ring", "llff_fern": "llff_fern/images"}


# ------------------------------------------------------------------ scenes
def prepare(work: Path, name: str, data: Path, max_side: int | None = None) -> Path:
    """A trainable scene folder (cached in ``work``): ``demo-small`` (16 views
    128x96, ground-truth poses), ``demo`` (the demo scene through ingest +
    sfm like the pipeline) or a real scene of :data:`PHOTOS` under ``data``,
    ingested at ``max_side`` px long side if given, then posed by SfM."""
    from gs2e.demo.io import generate_demo_scene
    from gs2e.demo.settings import DemoSettings

    if name == "demo-small":
        out = work / "demo_small"
        if not (out / "scene.json").exists():
            generate_demo_scene(out, DemoSettings.defaults(
                n_views=16, width=128, height=96, n_points=3000))
        return out
    out = work / f"{name}_sfm"
    if (out / "scene.json").exists():
        return out

    def gs2e_cli(*args):
        subprocess.run([sys.executable, "-m", "gs2e", *map(str, args)], check=True, env=gs2e_env(REPO),
                       capture_output=True)

    ing = work / f"{name}_ingest"
    if name == "demo":
        raw = work / "demo_raw"
        if not (raw / "scene.json").exists():
            gs2e_cli("demo-scene", "--out", raw)
        gs2e_cli("ingest", "--layout", "demo", "--src", raw, "--out", ing)
    else:
        size = ["--config-json", json.dumps({"max_side": max_side})] if max_side else []
        gs2e_cli("ingest", "--layout", "folder", "--src", data / PHOTOS[name], "--out", ing, *size)
    gs2e_cli("sfm", "--scene", ing, "--out", out)
    return out


# ------------------------------------------------------------------ render timings
def time_call(render_once, params, reps: int):
    """Seconds of forward and forward+backward (loss = sum of image and alpha)
    of ``render_once()``, a closure returning (image, alpha, depth, meta),
    with the gradients of ``params`` cleared before each call: dict of the
    median and min wall seconds over ``reps``, plus the median process CPU
    seconds of forward+backward; and the last call's meta."""
    t_f, t_fb, c_fb = [], [], []
    meta = None
    params = list(params)
    for _ in range(reps):
        for x in params:
            x.grad = None
        with clock() as fb:
            with clock() as f:
                img, alpha, depth, meta = render_once()
            (img.sum() + alpha.sum()).backward()
        c_fb.append(fb.cpu_s)
        t_f.append(f.wall_s)
        t_fb.append(fb.wall_s)
    return dict(fwd_s=float(np.median(t_f)), fwd_min_s=float(np.min(t_f)),
                fwd_bwd_s=float(np.median(t_fb)), fwd_bwd_min_s=float(np.min(t_fb)),
                fwd_bwd_cpu_s=float(np.median(c_fb))), meta


def trained_cameras(names: list[str]):
    """(name, params with gradients on, model info, camera) for each trained
    model ``names`` of bench_event_sampling.py (:func:`event_runs.build_scenes`),
    seen from a third of the way along its base_medium trajectory at its
    training size and at twice it."""
    from event_runs import build_scenes
    from gs2e.splat.model import load_model
    from gs2e.splat.rasterize import SplatCamera
    from gs2e.trajectory import load_trajectory

    for name, d in build_scenes(names).items():
        p, info = load_model(d / "splat")
        for x in p.values():
            x.requires_grad_(True)
        tr = load_trajectory(d / "trajectories" / "base_medium.npz")
        c2w = tr.pose_at(np.array([tr.duration_us // 3]))[0]
        for scale in (1, 2):
            K = tr.K * scale
            yield name, p, info, SplatCamera.from_c2w(c2w, K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                                                      tr.width * scale, tr.height * scale)
