"""A model trained elsewhere (official 3DGS, gsplat) as the train stage's
output (``splat.model_source: ply``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch

from gs2e.common.errors import InputError
from gs2e.io.scene import Scene
from gs2e.splat.evaluate import evaluate
from gs2e.splat.model import to_params
from gs2e.splat.output import write_train_output
from gs2e.splat.ply import read_ply
from gs2e.splat.views import View


def find_model_ply(path: str | Path) -> tuple[Path, int | None]:
    """The PLY file of ``path`` and its iteration count: a file as it is (count
    unknown: None), a folder's latest ``point_cloud/iteration_N/point_cloud.ply``."""
    path = Path(path)
    if not path.is_dir():
        return path, None
    its = sorted(path.glob("point_cloud/iteration_*/point_cloud.ply"),
                 key=lambda q: int(q.parent.name.split("_")[1]))
    if not its:
        raise InputError(f"{path}: no point_cloud/iteration_*/point_cloud.ply")
    return its[-1], int(its[-1].parent.name.split("_")[1])


def import_ply(ply_path: str | None, scene: Scene, scene_dir: Path, out_dir: Path,
               test_views: list[View], background: torch.Tensor, stats: dict[str, Any],
               scene_id: str | None, view_sizes: dict[str, list[int]] | None = None) -> dict[str, Any]:
    """Evaluate the model at ``ply_path`` on the held-out views and write it as
    the stage's output; returns ``stats`` updated with the model's figures."""
    if not ply_path:
        raise InputError("splat.model_source is 'ply' but splat.ply_path is not set")
    path, iterations = find_model_ply(ply_path)
    g = read_ply(path)
    sh_deg = int(round(math.sqrt(g["sh"].shape[1]))) - 1
    # scored with the window every stage will render it with (splat.window), not
    # necessarily the one it was trained with (official 3DGS: cut)
    ev = evaluate(to_params(g), test_views, background, sh_deg, stats["backend"], stats["window"])
    stats.update({"source": "ply", "ply_path": str(path), "iterations": iterations,
                  "n_gaussians": int(len(g["means"])), "train_time_s": None,
                  "test_psnr": ev["psnr"], "test_ssim": ev["ssim"], "test_lpips": None,
                  "sh_degree": sh_deg, "sh_degree_final": sh_deg})
    write_train_output(out_dir, scene, g, iterations or 0, sh_deg, stats, [], scene_id, scene_dir, view_sizes)
    return stats
