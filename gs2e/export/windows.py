"""Aligned event windows: for every frame of a trajectory, the index range of
its events in ``events.h5``, so that ``events[i0:i1]`` needs no search.

``windows/<trajectory>.parquet`` (one row per frame, written by the workflow's
``windows`` rule next to ``frames/`` and ``events/``)::

    frame           int64   frame index (rgb/NNNNNN.png, blur/NNNNNN.png)
    t_us            int64   frame time, absolute trajectory microseconds
    inter_t0_us     Int64   previous frame's time (null for frame 0)
    inter_t1_us     int64   this frame's time
    inter_covered   bool    the events of [inter_t0_us, inter_t1_us) were simulated
    inter_i0/_i1    Int64   events[inter_i0:inter_i1] have inter_t0_us <= t < inter_t1_us
    exp_t0_us       Int64   exposure start of the blurred frame
    exp_t1_us       Int64   exposure end (events with exp_t0_us <= t < exp_t1_us)
    exp_covered     bool    the exposure was simulated
    exp_i0/_i1      Int64   events[exp_i0:exp_i1] lie in the exposure

The exposure is the renderer's: ``exposure_us`` centred on the frame time and
clipped to the trajectory ([first frame, last frame]); its bounds are the
ceilings of the exact (fractional) bounds, which select the same integer event
times. Frames without a blurred image (exposure_us = 0) have null exposure
columns. Indices are null, and ``*_covered`` false, for windows that reach
outside the simulated span (events simulated only on part of the trajectory):
such a window is "not simulated", never "no events".

The file's parquet metadata (key ``gs2e_windows``, JSON) holds the events
file name, its ``t_offset_us``, the simulated span ``[sim_start_us,
sim_end_us]`` (inclusive), ``n_events`` and the conventions.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from gs2e.common.atomic import atomic_path
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.export.conventions import check_times_us

log = get_logger("gs2e.export")

META_KEY = b"gs2e_windows"
FORMAT_VERSION = 1


def simulated_span_us(events_dir: str | Path, t_offset_us: int) -> tuple[int, int]:
    """Inclusive span [start, end] (absolute us) over which events were simulated.

    The event stage starts at ``t_offset`` (its first sample) and records the
    duration up to its last sample in ``stats.json`` (``stats.duration_s``).
    """
    p = Path(events_dir) / "stats.json"
    try:
        dur_s = json.loads(p.read_text())["stats"]["duration_s"]
    except (OSError, KeyError, TypeError, json.JSONDecodeError) as exc:
        raise InputError(f"{p}: cannot read the simulated duration stats.duration_s ({exc})") from exc
    if dur_s is None or not math.isfinite(float(dur_s)) or float(dur_s) < 0:
        raise InputError(f"{p}: stats.duration_s is {dur_s!r}, not a duration")
    return int(t_offset_us), int(t_offset_us) + int(round(float(dur_s) * 1e6))


def exposure_bounds_us(t_us: np.ndarray, exposure_us: np.ndarray, t_first_us: int,
                       t_last_us: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer bounds [a, b) of each blurred frame's exposure (the render stage's
    ``t +- exposure/2`` clipped to the trajectory), as ceilings of the exact
    bounds: an integer event time lies in [a, b) iff it lies in the exact one."""
    t = np.asarray(t_us, np.float64)
    half = np.asarray(exposure_us, np.float64) / 2
    a = np.maximum(float(t_first_us), t - half)
    b = np.minimum(float(t_last_us), t + half)
    return np.ceil(a).astype(np.int64), np.ceil(b).astype(np.int64)


def _nullable(values: np.ndarray, keep: np.ndarray) -> pd.Series:
    """Int64 column with null where ``keep`` is false."""
    return pd.Series(pd.array(np.asarray(values, np.int64), dtype="Int64")).mask(~np.asarray(keep, bool))


def compute_windows(t_frames_us: np.ndarray, exposure_us: np.ndarray, event_t_us: np.ndarray,
                    span_us: tuple[int, int]) -> pd.DataFrame:
    """The windows table (see module docstring) from frame times (N,), per-frame
    exposures (N,) in us, sorted absolute event times (M,) and the simulated
    span (inclusive, absolute us)."""
    t = check_times_us(t_frames_us, "frame times")
    if t.size and np.any(np.diff(t) <= 0):
        raise InputError("frame times are not strictly increasing")
    ev_t = check_times_us(event_t_us, "event times")
    s0, s1 = int(span_us[0]), int(span_us[1])
    n = len(t)
    exposure = np.asarray(exposure_us, np.float64)

    def covered(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        # [a, b) holds integer times a .. b-1; all of them must be simulated
        return (a >= s0) & (b - 1 <= s1)

    def index_cols(a: np.ndarray, b: np.ndarray, ok: np.ndarray) -> tuple[pd.Series, pd.Series]:
        return (_nullable(np.searchsorted(ev_t, a, side="left"), ok),
                _nullable(np.searchsorted(ev_t, b, side="left"), ok))

    df = pd.DataFrame({"frame": np.arange(n, dtype=np.int64), "t_us": t})
    # between consecutive frames: [t_{i-1}, t_i)
    a = np.concatenate([t[:1], t[:-1]])
    ok = covered(a, t)
    ok[:1] = False  # frame 0 has no previous frame
    df["inter_t0_us"] = _nullable(a, np.arange(n) > 0)
    df["inter_t1_us"] = t
    df["inter_covered"] = ok
    df["inter_i0"], df["inter_i1"] = index_cols(a, t, ok)
    # over each blurred frame's exposure
    has_blur = exposure > 0
    ea, eb = (exposure_bounds_us(t, exposure, int(t[0]), int(t[-1])) if n
              else (np.zeros(0, np.int64), np.zeros(0, np.int64)))
    ok = covered(ea, eb) & has_blur
    df["exp_t0_us"] = _nullable(ea, has_blur)
    df["exp_t1_us"] = _nullable(eb, has_blur)
    df["exp_covered"] = ok
    df["exp_i0"], df["exp_i1"] = index_cols(ea, eb, ok)
    return df


def write_windows(frames_dir: str | Path, events_dir: str | Path, out_path: str | Path) -> pd.DataFrame:
    """Compute the windows of one trajectory (frames folder of ``gs2e render``,
    events folder of ``gs2e events``) and write them to ``out_path`` (atomic)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from gs2e.events.io import read_h5
    from gs2e.render.dataset import read_frames_table

    frames_dir, events_dir = Path(frames_dir), Path(events_dir)
    try:
        frames = read_frames_table(frames_dir)
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{frames_dir / 'frames.parquet'}: cannot read the frames table ({exc})") from exc
    ev, attrs = read_h5(events_dir / "events.h5")
    span = simulated_span_us(events_dir, attrs["t_offset"])
    df = compute_windows(frames["t_us"].to_numpy(), frames["exposure_us"].to_numpy(), ev.t, span)
    meta = {"version": FORMAT_VERSION, "events_file": "events.h5",
            "t_offset_us": int(attrs["t_offset"]), "sim_start_us": span[0], "sim_end_us": span[1],
            "n_events": len(ev), "n_frames": len(df),
            "width": int(attrs.get("width", 0)), "height": int(attrs.get("height", 0)),
            "polarity": "events.h5 p: 1 = ON, 0 = OFF",
            "time": "absolute trajectory microseconds (int64); windows are [t0, t1)"}
    table = pa.Table.from_pandas(df, preserve_index=False)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}),
                                           META_KEY: json.dumps(meta, sort_keys=True).encode()})
    with atomic_path(out_path) as tmp:
        pq.write_table(table, tmp)
    n_cov = int(df["inter_covered"].sum())
    log.info("%s: %d frames, %d events, %d/%d inter-frame windows covered (span %d..%d us)",
             out_path, len(df), len(ev), n_cov, max(0, len(df) - 1), span[0], span[1])
    return df


def read_windows(path: str | Path) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A windows table and its metadata (see module docstring)."""
    import pyarrow.parquet as pq

    path = Path(path)
    try:
        table = pq.read_table(path)
        meta = json.loads((table.schema.metadata or {})[META_KEY])
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{path}: not a gs2e windows table ({exc})") from exc
    return table.to_pandas(), meta


def covered_frame_range(windows: pd.DataFrame, where: str) -> tuple[int, int]:
    """First and last frame index (inclusive) of the longest run of frames whose
    consecutive windows are all covered: the frames an export can use."""
    cov = windows["inter_covered"].to_numpy(bool)
    best, start = (0, -1), None
    for i in range(1, len(cov) + 1):
        if i < len(cov) and cov[i]:
            start = i - 1 if start is None else start
        elif start is not None:
            if i - 1 - start > best[1] - best[0]:
                best = (start, i - 1)
            start = None
    if best[1] < 0:
        raise InputError(f"{where}: the simulated events cover fewer than two consecutive frames "
                         "(events simulated on too short a part of the trajectory); nothing to export")
    return best
