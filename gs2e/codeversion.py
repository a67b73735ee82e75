"""Version of the library code each workflow rule depends on.

Snakemake reruns a job when its params change, but not when an imported
library changes. Each rule therefore carries ``code_version(stage)`` in its
params: a hash of the source files of the subpackages the stage uses, so an
edit in gs2e/sfm reruns sfm and everything downstream, and an edit in
gs2e/events reruns only the event jobs.
"""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

PKG = Path(__file__).resolve().parent

# Stages write their one-row tables with gs2e.metrics.table only; the scene and
# dataset tables (metrics/collect.py) are the metrics stage's own code.
METRICS_WRITER = ("metrics/__init__.py", "metrics/table.py")

# Subpackages (or modules) each stage's code path imports.
STAGE_DEPS: dict[str, tuple[str, ...]] = {
    "demo": ("demo", "io", "common"),
    "ingest": ("io", "common", "config.py"),
    "sfm": ("sfm", "io", "common", *METRICS_WRITER),
    "train": ("splat", "io", "common", *METRICS_WRITER),
    "trajectory": ("trajectory", "io", "common", "config.py"),
    "render": ("render", "splat", "trajectory", "io", "common", *METRICS_WRITER),
    "events": ("events", "splat", "trajectory", "io", "common", *METRICS_WRITER),
    "metrics": ("metrics", "io", "common", "config.py"),
    "report": ("report", "events", "io", "common", "config.py", *METRICS_WRITER),
    # the windows table reads frames.parquet and events.h5 only
    "windows": ("export/__init__.py", "export/cli.py", "export/windows.py", "export/conventions.py",
                "events/io.py", "events/models.py", "render/dataset.py", "common"),
    "export": ("export", "events", "render", "trajectory", "io", "common", "config.py"),
}


@functools.lru_cache(maxsize=None)
def code_version(stage: str) -> str:
    """Short sha256 over the .py files a stage depends on (path + content)."""
    if stage not in STAGE_DEPS:
        raise KeyError(f"unknown stage '{stage}'")
    h = hashlib.sha256()
    for dep in STAGE_DEPS[stage] + ("cli.py", "__init__.py"):
        p = PKG / dep
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p] if p.exists() else []
        for f in files:
            h.update(str(f.relative_to(PKG)).encode())
            h.update(b"\0")
            h.update(f.read_bytes())
            h.update(b"\0")
    return h.hexdigest()[:16]
