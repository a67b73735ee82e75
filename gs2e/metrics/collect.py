"""The scene's metrics table and the dataset summary.

``scene_table`` joins the one-row tables every stage writes (sfm, train,
render, events) into one row per (scene, trajectory), each stage's columns
prefixed with its name (``sfm_registration_rate``, ``train_test_psnr``,
``render_frames_per_s``, ``events_rate_meps`` ...), plus provenance: the
package version, one ``code_version_<stage>`` per stage (see
gs2e.codeversion), the config hash and the seeds. ``summary`` concatenates
scene tables. Missing values stay missing (null).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd

from gs2e import __version__
from gs2e.codeversion import STAGE_ENTRY, code_version
from gs2e.common.errors import InputError
from gs2e.light.settings import split_run
from gs2e.config import scene_params_json
from gs2e.metrics.table import read_metrics, read_table

STAGE_FILES = {"sfm": "sfm/metrics.parquet", "train": "splat/metrics.parquet"}


def config_hash(config: dict) -> str:
    """16 hex digits of sha256 over the canonical JSON of a scene's config,
    without the location keys (scenes table path, results_dir)."""
    return hashlib.sha256(scene_params_json(config).encode()).hexdigest()[:16]


def _events_seed(scene_dir: Path, name: str) -> int | None:
    # The seed the events job actually used, as it recorded it.
    p = scene_dir / "events" / name / "stats.json"
    if not p.exists():
        return None
    seed = json.loads(p.read_text()).get("metadata", {}).get("seed")
    return None if seed is None else int(seed)


def _row(path: Path, prefix: str) -> dict:
    df = read_table(path)
    if len(df) != 1:
        raise InputError(f"{path}: expected one row, got {len(df)}")
    return {f"{prefix}_{k}": v for k, v in df.iloc[0].items() if k not in ("scene_id", "stage")}


def scene_table(scene_dir: str | Path, scene_id: str, trajectories: list[str], config: dict,
                seeds: dict[str, int] | None = None) -> pd.DataFrame:
    """One row per trajectory of the scene in ``scene_dir`` (results/<scene>).

    ``code_version_<stage>`` is the stage's code version when this table is
    written; the workflow reruns a stage when its code version changes (rule
    params), so with the default rerun triggers it is also the version that
    made the stage's outputs. ``seed_events`` is per trajectory, read from the
    events job's stats.json.
    """
    scene_dir = Path(scene_dir)
    base = {"scene_id": scene_id, "gs2e_version": __version__,
            **{f"code_version_{s}": code_version(s) for s in STAGE_ENTRY},
            "config_hash": config_hash(config),
            **{f"seed_{k}": v for k, v in (seeds or {}).items()}}
    for stage, rel in STAGE_FILES.items():
        p = scene_dir / rel
        if p.exists():
            base.update(_row(p, stage))
    idx = scene_dir / "trajectories" / "trajectories.json"
    traj_info = {}
    if idx.exists():
        for t in json.loads(idx.read_text()).get("trajectories", []):
            traj_info[t["name"]] = t
    rows = []
    for name in trajectories:
        row = dict(base, seed_events=_events_seed(scene_dir, name), trajectory=name)
        traj, light = split_run(name)  # a run <trajectory>@<condition>: the light's own rows
        if light is not None:
            row["light"] = light
        t = traj_info.get(traj, {})
        for k in ("kind", "method", "preset", "n_poses", "duration_us", "length", "max_rel_step_error"):
            row[f"trajectory_{k}"] = t.get(k)
        for stage, rel in (("render", f"frames/{name}/metrics.parquet"), ("events", f"events/{name}/stats.parquet")):
            p = scene_dir / rel
            if p.exists():
                row.update(_row(p, stage))
        rows.append(row)
    return pd.DataFrame(rows)


def summary(tables: list[str | Path], status: str | Path | None = None) -> pd.DataFrame:
    """Concatenate scene tables (one row per scene x trajectory).

    With ``status`` (the ``scene_status.parquet`` of ``gs2e dataset``,
    :mod:`gs2e.dataset.status`), every row gets its scene's ``status``
    (passed / failed), ``failed_stage`` and ``fail_reason``, and a failed scene
    without a table becomes one row with only those (the rest missing).
    """
    df = read_metrics(tables) if tables else pd.DataFrame({"scene_id": pd.Series([], dtype=object)})
    if status is None:
        return df
    cols = ["scene_id", "status", "failed_stage", "reason"]
    st = read_table(status)
    if set(cols) - set(st.columns):
        raise InputError(f"{status}: not a scene status table (no column {sorted(set(cols) - set(st.columns))[0]})")
    st = st[cols]
    st = st.rename(columns={"reason": "fail_reason"})
    df = df.drop(columns=[c for c in ("status", "failed_stage", "fail_reason") if c in df.columns])
    out = df.merge(st, on="scene_id", how="left")
    out["status"] = out["status"].fillna("passed")  # a scene the status table does not list
    lost = st[(st["status"] == "failed") & ~st["scene_id"].isin(df["scene_id"])]
    return pd.concat([out, lost], ignore_index=True)
