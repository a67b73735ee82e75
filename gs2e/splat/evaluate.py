"""Image quality of a model at a scene's views: mean PSNR/SSIM for the trainer,
per-view renders and figures for ``gs2e render-views``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from gs2e.common.atomic import atomic_dir
from gs2e.common.log import get_logger
from gs2e.common.progress import progress
from gs2e.io.images import to_u8, write_png
from gs2e.io.scene import read_scene
from gs2e.splat.backend import resolve_backend
from gs2e.splat.loss import psnr, ssim
from gs2e.splat.model import load_model, model_window, render
from gs2e.splat.views import View, load_views, split_views

log = get_logger("gs2e.splat")


def score_view(p: dict[str, torch.Tensor], view: View, background: torch.Tensor, sh_degree: int,
               backend: str = "cpu", window: str = "cut") -> tuple[torch.Tensor, float, float]:
    """The model's render of ``view`` at full resolution ((H, W, 3) in [0, 1],
    with the compositing ``window``), its PSNR (dB) and SSIM against the
    view's image (call under no_grad)."""
    cam, gt = view.camera(1)
    img = render(p, cam, background, sh_degree, backend, window=window)[0].clamp(0, 1)
    return img, psnr(img, gt), float(ssim(img, gt))


def evaluate(p: dict[str, torch.Tensor], views: list[View], background: torch.Tensor,
             sh_degree: int, backend: str = "cpu", window: str = "cut") -> dict[str, float]:
    """Mean PSNR (dB) and SSIM over ``views`` at full resolution (NaN without
    views), rendered with the compositing ``window``."""
    if not views:
        return {"psnr": float("nan"), "ssim": float("nan")}
    with torch.no_grad():
        scores = [score_view(p, v, background, sh_degree, backend, window)[1:] for v in views]
    return {"psnr": float(np.mean([s[0] for s in scores])), "ssim": float(np.mean([s[1] for s in scores]))}


def render_views(model_dir: str | Path, scene_dir: str | Path, out_dir: str | Path,
                 which: str = "test", test_every: int | None = None, backend: str = "cpu") -> list[dict]:
    """Render ``which`` views (test/train/all) of ``scene_dir`` with the model in
    ``model_dir``; writes ``<name>.png`` renders and ``metrics.parquet`` with
    per-view PSNR (dB) and SSIM against the scene's images. The hold-out split
    (``test_every``) and background are the model's own unless given.
    ``backend``: 'cpu', 'gsplat' or 'auto' (see gs2e.splat.backend)."""
    from gs2e.metrics.table import write_metrics

    p, info = load_model(model_dir)
    backend = resolve_backend(backend, "--backend")
    scene_dir = Path(scene_dir)
    scene = read_scene(scene_dir)
    trained = info.get("view_sizes") or {}  # the sizes the model was trained and scored at
    views = load_views(scene_dir, scene, [1], [tuple(trained.get(f.name, scene.frame_size(i)))
                                                for i, f in enumerate(scene.frames)])
    if test_every is None:
        test_every = int(info.get("test_every", 8))
    train_v, test_v = split_views(views, test_every)
    sel = {"test": test_v, "train": train_v, "all": views}[which]
    bg = torch.tensor(info.get("background", [0.0, 0.0, 0.0]), dtype=torch.float32)
    rows = []
    with atomic_dir(out_dir) as out, torch.no_grad():
        for v in progress(sel, desc="rendering views"):
            img, view_psnr, view_ssim = score_view(p, v, bg, int(info["sh_degree"]), backend,
                                                   model_window(info))
            write_png(out / (Path(v.name).stem + ".png"), to_u8(img.numpy()))
            rows.append({"view": v.name, "psnr": view_psnr, "ssim": view_ssim})
        write_metrics(out / "metrics.parquet", rows, stage="render-views")
    if rows:
        log.info("%d views: mean PSNR %.2f dB, SSIM %.4f", len(rows),
                 np.mean([r["psnr"] for r in rows]), np.mean([r["ssim"] for r in rows]))
    return rows
