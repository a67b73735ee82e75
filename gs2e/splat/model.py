"""The Gaussian model: load, save, convert, render.

What the trainer produces and every later stage consumes. A model folder
(``gs2e train`` output) holds ``model.json`` (format, SH degree, size of the
training views, background, hold-out split) and the official
``point_cloud/iteration_N/point_cloud.ply``.

Parameters in memory are a dict of torch tensors (one dtype):
``means`` (N,3), ``quats`` (N,4) w,x,y,z, ``log_scales`` (N,3),
``opacity_logits`` (N,), ``sh_dc`` (N,1,3) and ``sh_rest`` (N,K-1,3) (split so
that the two get their own learning rates).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from gs2e.common.atomic import write_json_atomic
from gs2e.common.errors import InputError
from gs2e.splat.ply import read_ply, write_ply
from gs2e.splat.rasterize import SplatCamera, rasterize

MODEL_FORMAT = "gs2e-splat"


def to_params(g: dict[str, np.ndarray], dtype=torch.float32) -> dict[str, torch.Tensor]:
    """Arrays (means, quats, log_scales, opacity_logits, sh (N,K,3)) -> parameter tensors."""
    sh = torch.as_tensor(np.asarray(g["sh"]), dtype=dtype)
    return {
        "means": torch.as_tensor(np.asarray(g["means"]), dtype=dtype).contiguous(),
        "quats": torch.as_tensor(np.asarray(g["quats"]), dtype=dtype).contiguous(),
        "log_scales": torch.as_tensor(np.asarray(g["log_scales"]), dtype=dtype).contiguous(),
        "opacity_logits": torch.as_tensor(np.asarray(g["opacity_logits"]), dtype=dtype).contiguous(),
        "sh_dc": sh[:, :1].contiguous(),
        "sh_rest": sh[:, 1:].contiguous(),
    }


def from_params(p: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    """Parameter tensors -> arrays (the inverse of :func:`to_params`)."""
    sh = torch.cat([p["sh_dc"], p["sh_rest"]], dim=1)
    return {"means": p["means"].detach().numpy(), "quats": p["quats"].detach().numpy(),
            "log_scales": p["log_scales"].detach().numpy(),
            "opacity_logits": p["opacity_logits"].detach().numpy(), "sh": sh.detach().numpy()}


def render(p: dict[str, torch.Tensor], cam: SplatCamera, background: torch.Tensor, sh_degree: int,
           backend: str = "cpu", grad_dtype: str = "float64", window: str = "cut"):
    """Differentiable render of the model: (image, alpha, depth, meta), see
    :func:`gs2e.splat.rasterize.rasterize` (``grad_dtype``: what the CPU
    compositing computes in when a gradient may follow; ``window``: the
    compositing window, :func:`model_window`)."""
    sh = torch.cat([p["sh_dc"], p["sh_rest"]], dim=1)
    return rasterize(p["means"], p["quats"], p["log_scales"], p["opacity_logits"], sh, cam,
                     background=background, sh_degree=sh_degree, backend=backend,
                     grad_dtype=grad_dtype, window=window)


def model_window(info: dict) -> str:
    """The compositing window a model was trained with (model.json's
    ``window``; 'cut' for models from before it was recorded and imported
    PLYs, which 3DGS trained with that window)."""
    return str(info.get("window", "cut"))


def save_model(out: Path, g: dict[str, np.ndarray], iterations: int, sh_degree: int,
               info: dict) -> str:
    """Write the PLY of the active SH degree and ``model.json`` into the folder
    ``out`` (already a temporary folder of the caller's atomic output).
    ``info`` adds keys to model.json. Returns the PLY path relative to ``out``."""
    k = (sh_degree + 1) ** 2
    g = dict(g)
    g["sh"] = g["sh"][:, :k]  # store only the active degree
    rel = f"point_cloud/iteration_{iterations}/point_cloud.ply"
    write_ply(Path(out) / rel, **g)
    write_json_atomic(Path(out) / "model.json", {
        "format": MODEL_FORMAT, "version": 1, "ply": rel, "iterations": iterations,
        "sh_degree": sh_degree, "n_gaussians": int(len(g["means"])), **info})
    return rel


def load_model(model_dir: str | Path) -> tuple[dict[str, torch.Tensor], dict]:
    """Read a ``gs2e train`` output folder: (params, model.json)."""
    model_dir = Path(model_dir)
    try:
        info = json.loads((model_dir / "model.json").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read {model_dir / 'model.json'}: {exc}") from exc
    if not isinstance(info, dict) or "ply" not in info or "sh_degree" not in info:
        raise InputError(f"{model_dir / 'model.json'}: not a gs2e model (needs 'ply' and 'sh_degree')")
    return to_params(read_ply(model_dir / info["ply"])), info
