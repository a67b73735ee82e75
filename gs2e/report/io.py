"""Reading a results tree for the report. Every reader returns None for an
input that does not exist (the report shows it as missing); an input that
exists but cannot be read is an InputError naming the file."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd

from gs2e.common.errors import InputError
from gs2e.events.models import Events
from gs2e.io.views import natural_key
from gs2e.metrics.table import read_table


def _read_parquet(path: Path) -> pd.DataFrame | None:
    return read_table(path) if path.exists() else None


def read_bench(results_dir: Path) -> pd.DataFrame | None:
    """The dataset's bench table (gs2e bench-summary), None if absent."""
    return _read_parquet(results_dir / "bench.parquet")


def read_bench_real(results_dir: Path) -> pd.DataFrame | None:
    """The video task on real recordings (gs2e bench-real), None if absent."""
    return _read_parquet(Path(results_dir) / "bench_real.parquet")


def read_sim2real(folder: Path) -> pd.DataFrame | None:
    """A scene's sim-to-real distances (gs2e bench-sim2real), or None."""
    return _read_parquet(Path(folder) / "distances.parquet")


def read_summary(results_dir: Path) -> pd.DataFrame | None:
    return _read_parquet(Path(results_dir) / "summary.parquet")


def read_scene_status(results_dir: Path) -> pd.DataFrame | None:
    """The status table ``gs2e dataset`` wrote (gs2e.dataset.status), or None."""
    return _read_parquet(Path(results_dir) / "scene_status.parquet")


def list_scenes(results_dir: Path, summary: pd.DataFrame | None) -> list[str]:
    """Scene ids: those of the summary, else every sub-folder with a metrics
    table or a trained model."""
    if summary is not None and "scene_id" in summary:
        return list(dict.fromkeys(summary["scene_id"].astype(str)))
    root = Path(results_dir)
    return sorted((p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith(".")
                   and ((p / "metrics.parquet").exists() or (p / "splat").exists())), key=natural_key)


def scene_trajectories(scene_dir: Path, summary: pd.DataFrame | None, scene: str) -> list[str]:
    """Trajectories with rendered frames or events (summary order first)."""
    names: list[str] = []
    if summary is not None and "trajectory" in summary:
        names += [str(t) for t in summary.loc[summary["scene_id"].astype(str) == scene, "trajectory"]
                  if t is not None]
    for sub in ("frames", "events"):
        d = scene_dir / sub
        if d.is_dir():
            names += sorted((p.name for p in d.iterdir() if p.is_dir() and not p.name.startswith(".")),
                            key=natural_key)
    return list(dict.fromkeys(names))


def read_curve(scene_dir: Path) -> pd.DataFrame | None:
    """splat/curve.parquet: held-out quality against training time."""
    c = _read_parquet(scene_dir / "splat" / "curve.parquet")
    if c is not None and not {"train_time_s", "psnr"} <= set(c.columns):
        raise InputError(f"{scene_dir / 'splat' / 'curve.parquet'}: needs columns train_time_s and psnr")
    return c


# Workflow jobs in pipeline order (benchmark files are named after the job).
STAGE_ORDER = ("demo_scene", "ingest", "sfm", "train", "trajectory", "render", "events",
               "metrics", "summary", "report")


_USAGE_LINE = re.compile(r"gs2e \S+ finished in ([0-9.]+) s \(([0-9.]+) CPU-s, peak RSS ([0-9.]+) MB\)")


def read_job_usage(log_path: Path) -> dict[str, float] | None:
    """Exact CPU seconds and peak memory of a job from its log: the ``gs2e ...
    finished in W s (C CPU-s, peak RSS M MB)`` lines every gs2e command ends
    with (:func:`gs2e.common.log.process_usage`), summed over the commands of
    the job (peak: the largest). None if the log is absent or has no such line
    (a failed job, or a log of an older gs2e)."""
    try:
        text = Path(log_path).read_text(errors="replace")
    except OSError:
        return None
    hits = _USAGE_LINE.findall(text)
    if not hits:
        return None
    return {"wall_s": sum(float(w) for w, _, _ in hits), "cpu_s": sum(float(c) for _, c, _ in hits),
            "max_rss_mb": max(float(m) for _, _, m in hits)}


def read_benchmark_file(path: Path) -> dict[str, float] | None:
    """The last row (the last repeat) of one Snakemake benchmark TSV as floats
    (s, max_rss in MB, cpu_time in s, ...; '-'/'NA' -> nan, the h:m:s text
    column dropped); None if it has no rows.

    Snakemake samples CPU time and memory (every 0.5 s for the first 15 s, then
    every 30 s) and loses what a job does after its last sample: up to 30 s of
    CPU per job. Where the job's log (``../logs/<job>.log``) has gs2e's exact
    usage, ``cpu_time`` and ``max_rss`` are those, Snakemake's samples are kept
    as ``cpu_time_sampled`` / ``max_rss_sampled``, and ``usage_exact`` is 1."""
    try:
        df = pd.read_csv(path, sep="\t", na_values=["-", "NA"])
    except Exception as exc:
        raise InputError(f"{path}: not a readable benchmark table ({exc})") from exc
    if len(df) == 0:
        return None
    row = pd.to_numeric(df.iloc[-1].drop(labels=["h:m:s"], errors="ignore"), errors="coerce")
    out = {str(k): float(v) for k, v in row.items()}
    usage = read_job_usage(Path(path).parent.parent / "logs" / (Path(path).stem + ".log"))
    out["usage_exact"] = float(usage is not None)
    if usage is not None:
        out["cpu_time_sampled"], out["max_rss_sampled"] = out.get("cpu_time", np.nan), out.get("max_rss", np.nan)
        out["cpu_time"], out["max_rss"] = usage["cpu_s"], usage["max_rss_mb"]
    return out


def read_benchmarks(bench_dir: Path) -> pd.DataFrame | None:
    """Snakemake benchmark TSVs of a folder, one row per file (its last
    repeat), ``rule`` = the file name without .tsv, in pipeline order; None
    if there are none."""
    files = sorted(Path(bench_dir).glob("*.tsv")) if Path(bench_dir).is_dir() else []
    rows = [{"rule": f.stem, **row} for f in files if (row := read_benchmark_file(f)) is not None]
    if not rows:
        return None
    df = pd.DataFrame(rows)
    rank = df["rule"].map(lambda r: next((i for i, p in enumerate(STAGE_ORDER)
                                          if r == p or r.startswith(p + "_")), len(STAGE_ORDER)))
    return df.assign(_r=rank).sort_values(["_r", "rule"], kind="stable").drop(columns="_r")


def read_results_benchmarks(results_dir: Path) -> list[dict]:
    """Every job's benchmark in a results tree: one dict per
    ``<scene>/benchmarks/<job>.tsv`` (``scene`` = the folder) and per
    dataset-level ``benchmarks/<job>.tsv`` (``scene`` = None), with ``job``,
    ``path`` and the values of :func:`read_benchmark_file`."""
    results_dir = Path(results_dir)
    files = sorted(results_dir.glob("*/benchmarks/*.tsv")) + sorted(results_dir.glob("benchmarks/*.tsv"))
    out = []
    for f in files:
        row = read_benchmark_file(f)
        if row is not None:
            scene = f.parent.parent.name if f.parent.parent != results_dir else None
            out.append({"scene": scene, "job": f.stem, "path": f, **row})
    return out


def scene_cpu_min(results_dir: Path) -> dict[str, float]:
    """CPU minutes of every scene's jobs (:func:`read_results_benchmarks`: exact
    where the job's log has gs2e's usage line)."""
    cpu: dict[str, float] = {}
    for r in read_results_benchmarks(Path(results_dir)):
        v = r.get("cpu_time", float("nan"))
        if r["scene"] is not None and np.isfinite(v):
            cpu[r["scene"]] = cpu.get(r["scene"], 0.0) + v / 60.0
    return cpu


def read_frames_index(frames_dir: Path) -> pd.DataFrame | None:
    """frames/<traj>/frames.parquet (frame, file, t_us, ...)."""
    return _read_parquet(frames_dir / "frames.parquet")


def read_frame(frames_dir: Path, kind: str, file: str) -> np.ndarray | None:
    """uint8 RGB (H, W, 3) of frames/<traj>/<kind>/<file> (kind rgb = sharp,
    blur = motion-blurred), None if absent."""
    from gs2e.io.images import read_image

    p = frames_dir / kind / file
    return read_image(p) if p.exists() else None


def aedat4_source(path: Path) -> str | None:
    """Camera name recorded in an AEDAT4 header (e.g. 'DVXplorer'), or None."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(1 << 16).decode("latin-1")
    except OSError:
        return None
    m = re.search(r'key="source" type="string">([^<]+)<', head)
    # The source is '<model>_<serial>'; the serial says nothing to the reader.
    return m.group(1).split("_")[0] if m else None


def read_real_events(path: str | Path) -> tuple[Events, tuple[int, int], str]:
    """A real recording (.aedat4, .raw, .dat, .h5, .npz; text needs a size so is refused)
    -> (events, (H, W), label naming the sensor, resolution and file)."""
    from gs2e.events.io import read_events

    path = Path(path)
    if not path.exists():
        raise InputError(f"real event recording {path} does not exist "
                         "(metrics.real_events / --real-events)")
    ev, shape = read_events(path)
    if not shape or not all(shape):
        raise InputError(f"{path}: the sensor size is unknown (use an .aedat4, .raw, .dat, .h5 or .npz recording)")
    if len(ev) < 2:
        raise InputError(f"{path}: fewer than 2 events")
    if np.any(np.diff(ev.t) < 0):
        raise InputError(f"{path}: timestamps are not sorted")
    sensor = aedat4_source(path) if path.suffix.lower() == ".aedat4" else None
    H, W = shape
    label = f"real: {sensor + ' ' if sensor else ''}{W}x{H} ({path.name})"
    return ev, (int(H), int(W)), label


def read_sim_events(events_dir: Path) -> tuple[Events, tuple[int, int]] | None:
    """events/<traj>/events.h5 -> (events, (H, W)), None if absent."""
    from gs2e.events.io import read_h5

    p = events_dir / "events.h5"
    if not p.exists():
        return None
    ev, attrs = read_h5(p)
    return ev, (int(attrs["height"]), int(attrs["width"]))


def read_json(path: Path) -> dict | None:
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"{path}: not readable JSON ({exc})") from exc
