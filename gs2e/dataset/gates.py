"""Quality gates of one scene: what they read, and the verdict.

A gate compares one measured value of a finished scene with a threshold of the
``dataset`` section (:class:`gs2e.dataset.settings.DatasetSettings`); a
threshold of ``None`` is not checked. A value that cannot be measured (no
held-out views, a run without events) fails its gate as *missing*: a gate is
never passed on a value that was not computed.

The gates (docs/dataset.md):

- ``registered_fraction``: views with a camera after structure from motion over
  views ingested (``sfm_stats.json``: ``n_registered / n_views``);
- ``test_psnr_db``: the trained model's held-out PSNR (``train_stats.json``);
- ``events_per_pixel``: events per sensor pixel over a whole run, the least over
  the scene's runs (``events/<run>/stats.json``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from gs2e.common.errors import InputError
from gs2e.common.settings import require
from gs2e.dataset.settings import DatasetSettings

# gate -> (threshold key of the dataset section, what it is, how a value reads)
GATES = {
    "registered_fraction": ("min_registered_fraction", "registered views", "{:.1%}"),
    "test_psnr_db": ("min_test_psnr_db", "held-out PSNR", "{:.2f} dB"),
    "events_per_pixel": ("min_events_per_pixel", "events per pixel", "{:.3g}"),
}


# The gates a trained model can be judged by, before any render or event job.
MODEL_GATES = ("registered_fraction", "test_psnr_db")


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path} does not exist") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read as JSON ({exc})") from None


def _finite(v) -> float:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return math.nan
    return v if math.isfinite(v) else math.nan


def measure(scene_dir: str | Path, runs: list[str]) -> dict[str, float]:
    """The gates' values of a finished scene (NaN where one cannot be measured).

    Parameters
    ----------
    scene_dir : results/<scene>, with ``sfm/``, ``splat/`` and ``events/<run>/``.
    runs : the scene's runs whose events are read (``render.trajectories``).

    Returns
    -------
    dict with the gates' values (``registered_fraction`` in [0, 1],
    ``test_psnr_db`` in dB, ``events_per_pixel`` as a count per pixel) and what
    they come from: ``n_views``, ``n_registered``, ``test_ssim``,
    ``n_gaussians``, ``n_events`` (summed over the runs).

    Raises
    ------
    InputError naming a stats file that is absent or unreadable.
    """
    d = Path(scene_dir)
    sfm = _read_json(d / "sfm" / "sfm_stats.json")
    train = _read_json(d / "splat" / "train_stats.json")
    n_views, n_reg = _finite(sfm.get("n_views")), _finite(sfm.get("n_registered"))
    per_pixel, n_events = [], 0
    for run in runs:
        st = _read_json(d / "events" / run / "stats.json").get("stats", {})
        w, h, n = _finite(st.get("width")), _finite(st.get("height")), _finite(st.get("n_events"))
        n_events += 0 if math.isnan(n) else int(n)
        per_pixel.append(n / (w * h) if w > 0 and h > 0 else math.nan)
    return {
        "registered_fraction": n_reg / n_views if n_views > 0 else math.nan,
        "test_psnr_db": _finite(train.get("test_psnr")),
        # the least over the runs; NaN if any run's count is missing (never passed on a gap)
        "events_per_pixel": math.nan if not per_pixel or any(map(math.isnan, per_pixel)) else min(per_pixel),
        "n_views": n_views, "n_registered": n_reg,
        "test_ssim": _finite(train.get("test_ssim")),
        "n_gaussians": _finite(train.get("n_gaussians")),
        "n_events": float(n_events) if per_pixel else math.nan,  # no run measured: missing, not 0
    }


def failed_gates(values: dict[str, float], settings: DatasetSettings,
                 gates: tuple[str, ...] = tuple(GATES)) -> list[str]:
    """One reason per gate the values fail, in the order of :data:`GATES`.

    ``gates``: the gates checked (:data:`MODEL_GATES` before anything is
    rendered). A gate whose threshold is ``None`` is not checked; a NaN value
    fails its gate as missing. ``[]`` = the scene passes.
    """
    cfg = require(settings, DatasetSettings, "failed_gates")
    reasons = []
    for gate, (key, what, fmt) in GATES.items():
        if gate not in gates:
            continue
        limit = getattr(cfg, key)
        if limit is None:
            continue
        v = _finite(values.get(gate))
        if math.isnan(v):
            reasons.append(f"{what} missing (dataset.{key}: {fmt.format(limit)})")
        elif v < limit:
            reasons.append(f"{what} {fmt.format(v)} < {fmt.format(limit)} (dataset.{key})")
    return reasons
