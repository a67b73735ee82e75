"""``gs2e export``: one trajectory in one target layout, written atomically."""

from __future__ import annotations

import time
from pathlib import Path

from gs2e.common.atomic import atomic_dir
from gs2e.common.log import get_logger
from gs2e.common.settings import require
from gs2e.export.common import ExportOut
from gs2e.export.settings import ExportSettings
from gs2e.export.source import TrajectorySource

log = get_logger("gs2e.export")


def export_trajectory(scene_dir: str | Path, traj: str, fmt: str, out_dir: str | Path, cfg: ExportSettings,
                      windows_file: str | Path | None = None, scene_id: str | None = None,
                      seed: int = 0) -> dict:
    """Export trajectory ``traj`` of a scene's results folder in format ``fmt``
    (a name of :data:`gs2e.export.formats.FORMATS`) into ``out_dir`` (replaced
    atomically; nothing is left on error); ``seed`` for the formats that draw
    random numbers; ``cfg`` the ``export`` settings. Returns the manifest
    (also written as ``gs2e_export.json``)."""
    from gs2e.common.errors import ConfigError
    from gs2e.export.formats import FORMATS

    cfg = require(cfg, ExportSettings, "export_trajectory")
    if fmt not in FORMATS:
        raise ConfigError(f"export format '{fmt}' is not one of {', '.join(FORMATS)}")
    spec = FORMATS[fmt]
    run = spec.runner()
    t0 = time.perf_counter()
    src = TrajectorySource(Path(scene_dir), traj, Path(windows_file) if windows_file else None)
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        out = ExportOut(tmp, fmt, {"scene_id": scene_id, "trajectory": traj,
                                   "width": src.width, "height": src.height}, out_dir.resolve())
        run(src, out, cfg, seed=seed) if spec.seeded else run(src, out, cfg)
        out.manifest["time_s"] = time.perf_counter() - t0
        out.manifest["bytes"] = sum(p.stat().st_size for p in tmp.rglob("*") if p.is_file())
        out.write_manifest()
    log.info("export %s of %s/%s -> %s: %.1f MB in %.2f s (%d warnings)", fmt, scene_id or scene_dir,
             traj, out_dir, out.manifest["bytes"] / 1e6, out.manifest["time_s"],
             len(out.manifest["warnings"]))
    return out.manifest
