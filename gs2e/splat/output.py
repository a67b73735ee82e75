"""The train stage's output folder (``gs2e train``): what downstream stages read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gs2e.common.atomic import atomic_dir, write_json_atomic
from gs2e.io.scene import Scene
from gs2e.splat.model import save_model
from gs2e.splat.ply import write_cameras_json


def write_train_output(out_dir: Path, scene: Scene, g: dict[str, np.ndarray], iterations: int,
                       sh_degree: int, stats: dict, curve: list[dict], scene_id: str | None,
                       scene_dir: Path, view_sizes: dict[str, list[int]] | None = None) -> None:
    """Write ``out_dir`` atomically: the model (PLY of the active SH degree and
    ``model.json``), ``cameras.json``, ``train_stats.json``, ``metrics.parquet``
    (one row of ``stats``) and, for a trained model, ``curve.parquet`` (one row
    per evaluation). ``view_sizes``: the (W, H) each view was trained and
    scored at, by name (model.json; held-out renders use them)."""
    import pandas as pd

    from gs2e.metrics.table import write_metrics

    with atomic_dir(out_dir) as out:
        save_model(out, g, iterations, sh_degree, {
            "scene": str(scene_dir), "width": scene.width, "height": scene.height,
            "source": stats.get("source"), "background": stats["background"],
            "test_every": stats["test_every"], "view_sizes": view_sizes,
            "window": stats.get("window", "cut")})
        write_cameras_json(out / "cameras.json", scene)
        write_json_atomic(out / "train_stats.json", stats)
        write_metrics(out / "metrics.parquet", stats, scene_id=scene_id or out_dir.parent.name,
                      stage="train")
        if curve:
            pd.DataFrame(curve).to_parquet(out / "curve.parquet", index=False)
