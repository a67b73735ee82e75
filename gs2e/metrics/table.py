"""One-row-per-item metric tables as parquet files."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping

import pandas as pd

from gs2e.common.atomic import atomic_path
from gs2e.common.errors import InputError


def _clean(v: Any) -> Any:
    # NaN/inf mean "could not be computed": store them as missing (null).
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_metrics(path: str | Path, rows: Mapping[str, Any] | Iterable[Mapping[str, Any]],
                  **constant: Any) -> pd.DataFrame:
    """Write metric rows to ``path`` (parquet, atomically); ``constant`` columns
    (e.g. scene_id="x", stage="sfm") are added to every row."""
    if isinstance(rows, Mapping):
        rows = [rows]
    recs = [{**constant, **{k: _clean(v) for k, v in r.items()}} for r in rows]
    df = pd.DataFrame.from_records(recs)
    with atomic_path(path) as tmp:
        df.to_parquet(tmp, index=False, engine="pyarrow")
    return df


def read_table(path: str | Path) -> pd.DataFrame:
    """One parquet table; InputError naming the file if it is missing or corrupt."""
    try:
        return pd.read_parquet(path)
    except FileNotFoundError as exc:
        raise InputError(f"table {path} does not exist") from exc
    except Exception as exc:  # pyarrow raises several types on corrupt files
        raise InputError(f"{path}: not a readable parquet table ({exc})") from exc


def read_metrics(paths: str | Path | Iterable[str | Path]) -> pd.DataFrame:
    """Read and concatenate metric tables."""
    if isinstance(paths, (str, Path)):
        paths = [paths]
    frames = [read_table(p) for p in paths]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()
