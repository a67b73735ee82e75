"""Each scene's status after a run of many scenes: passed, or failed with the
stage that failed and a one-line reason.

A scene passed when every output it should make exists (its ``gate.json``
among them: :mod:`gs2e.dataset.gates`). Otherwise the reason is the error of
the earliest failed job in pipeline order: a job's log (``results/<scene>/logs/
<job>.log``, gs2e's stderr) that does not end with gs2e's ``finished in`` line.
Its one-line error (``gs2e <command>: error: ...``) is the reason; a job killed
outright (out of memory, a time limit) leaves no such line, and its log's last
line stands in. A scene with missing outputs and no failed log was not
finished (an interrupted run): that is its reason.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pandas as pd

from gs2e.common.errors import InputError
from gs2e.dataset.gates import measure

# Jobs in pipeline order (a log's name starts with its rule's name).
STAGE_ORDER = ("demo_scene", "ingest", "sfm", "train", "trajectory", "model_gate", "render", "events",
               "windows", "gate", "metrics", "export", "bench")
_ERROR = re.compile(r"^gs2e [\w-]+: error: (.*)$")
_DONE = " finished in "
# The columns of the status table (scene_status.parquet), in order.
COLUMNS = ("scene_id", "status", "failed_stage", "failed_job", "reason", "registered_fraction",
           "test_psnr_db", "test_ssim", "events_per_pixel", "n_views", "n_registered",
           "n_gaussians", "n_events")


def _stage(job: str) -> str:
    for s in sorted(STAGE_ORDER, key=len, reverse=True):
        if job == s or job.startswith(s + "_"):
            return s
    return job


def failed_jobs(log_dir: str | Path) -> list[tuple[str, str, str]]:
    """(stage, job, reason) of every job whose log shows it failed, in pipeline order.

    A log fails when it has no ``finished in`` line; its reason is gs2e's
    one-line error, else its last non-empty line, else ``"empty log"``.
    """
    out = []
    d = Path(log_dir)
    if not d.is_dir():
        return out
    for log in sorted(d.glob("*.log")):
        try:
            lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            continue
        if any(_DONE in ln for ln in lines):
            continue
        errors = [m.group(1) for ln in lines if (m := _ERROR.match(ln))]
        reason = errors[-1] if errors else (lines[-1][:300] if lines else "empty log")
        out.append((_stage(log.stem), log.stem, reason))
    rank = {s: i for i, s in enumerate(STAGE_ORDER)}
    return sorted(out, key=lambda r: (rank.get(r[0], len(rank)), r[1]))


def read_snakemake_summary(text: str, results_dir: str | Path,
                           scenes: list[str] | None = None) -> dict[str, list[tuple[str, str, str]]]:
    """The outputs of each scene from ``snakemake --summary`` (its TSV: output
    file, date, rule, log file(s), status, plan), as {scene: [(path, log,
    status)]}: the paths below ``results_dir/<scene>/``, in the summary's order.
    ``scenes``: the scene ids (None: every folder of ``results_dir`` named)."""
    root = Path(results_dir).as_posix().rstrip("/") + "/"
    rows = []
    lines = text.splitlines()
    for line in lines[1:] if lines and lines[0].startswith("output_file") else lines:
        cols = line.split("\t")
        if len(cols) >= 5 and Path(cols[0]).as_posix().startswith(root):
            rel = Path(cols[0]).as_posix()[len(root):]
            if "/" in rel:
                rows.append((rel.split("/", 1)[0], Path(cols[0]).as_posix(), cols[3].strip(), cols[4].strip()))
    out: dict[str, list[tuple[str, str, str]]] = (
        {sid: [] for sid in scenes} if scenes is not None else {r[0]: [] for r in rows})
    for sid, path, log, st in rows:
        if sid in out:
            out[sid].append((path, log, st))
    return out


def scene_status(results_dir: str | Path, outputs: dict[str, list[tuple[str, str, str]]]) -> pd.DataFrame:
    """The status table of a run: one row per scene (columns :data:`COLUMNS`).

    Parameters
    ----------
    results_dir : the run's results folder (``results/<scene>/`` below it).
    outputs : {scene id: [(path, log file, Snakemake's status)]} of every
        output the scene should make (:func:`read_snakemake_summary`). A scene
        passes when all of them exist; otherwise the reason is the earliest
        failed job (:func:`failed_jobs`) among the logs of its missing outputs.

    The gates' values (:func:`gs2e.dataset.gates.measure`) are filled wherever
    the scene's stats files exist, failed scenes included; NaN otherwise.
    """
    rows = []
    root = Path(results_dir)
    for sid, outs in outputs.items():
        sdir = root / sid
        missing = [(p, log) for p, log, _ in outs if not Path(p).exists()]
        row = {"scene_id": sid, "status": "passed", "failed_stage": None, "failed_job": None, "reason": None}
        if not outs:
            row.update(status="failed", reason="the workflow planned no outputs for this scene")
        elif missing:
            # the failed logs of the jobs whose outputs are missing; without those in
            # Snakemake's record (its metadata dropped), every failed log of the scene
            logs = {Path(log).resolve() for _, log in missing if log and log != "-"}
            fails = failed_jobs(sdir / "logs")
            if logs:
                fails = [f for f in fails if (sdir / "logs" / f"{f[1]}.log").resolve() in logs]
            if fails:
                stage, job, reason = fails[0]
            else:
                stage, job, reason = None, None, f"not finished: {missing[0][0]} is missing (the run was interrupted)"
            row.update(status="failed", failed_stage=stage, failed_job=job, reason=reason)
        row.update(_values(sdir, [p for p, _, _ in outs]))
        rows.append(row)
    return pd.DataFrame(rows, columns=list(COLUMNS))


def _values(sdir: Path, paths: list[str]) -> dict:
    """The gates' values of a scene: its gate.json's, else measured from what
    its stats files hold (a scene that failed on the way), NaN for the rest."""
    vals = {}
    try:
        vals = json.loads((sdir / "gate.json").read_text())["values"]
    except (OSError, ValueError, KeyError):
        runs = sorted({Path(p).name for p in paths if Path(p).parent.name == "events"})
        try:
            vals = measure(sdir, [r for r in runs if (sdir / "events" / r / "stats.json").is_file()])
        except InputError:  # no trained model: the views SfM registered, if it got that far
            try:
                s = json.loads((sdir / "sfm" / "sfm_stats.json").read_text())
                n, r = float(s["n_views"]), float(s["n_registered"])
                vals = {"n_views": n, "n_registered": r, "registered_fraction": r / n if n > 0 else math.nan}
            except (OSError, ValueError, KeyError, TypeError):
                pass
    return {k: vals.get(k, math.nan) for k in COLUMNS[5:]}


def write_status(table: pd.DataFrame, path: str | Path) -> bool:
    """Write the status table (parquet, atomically); returns False, writing
    nothing, when the file already holds the same table: the dataset-wide jobs
    that read it then do not rerun."""
    from gs2e.common.atomic import atomic_path

    p = Path(path)
    if p.is_file():
        try:
            if pd.read_parquet(p).equals(table):
                return False
        except Exception:  # unreadable: replaced below
            pass
    with atomic_path(p) as tmp:
        table.to_parquet(tmp, index=False)
    return True


def stage_label(value) -> str:
    """A failed scene's stage for its reason ('run' when no job's log failed;
    the table's missing stage may read None or NaN)."""
    return value if isinstance(value, str) and value else "run"


def read_failed(path: str | Path) -> dict[str, str]:
    """{scene id: "stage: reason"} of the failed scenes of a status table ({} if absent)."""
    from gs2e.metrics.table import read_table

    p = Path(path)
    if not p.is_file():
        return {}
    t = read_table(p)  # InputError naming the file if it is corrupt
    if not {"scene_id", "status", "failed_stage", "reason"} <= set(t.columns):
        raise InputError(f"{p}: not a scene status table (delete it, or run gs2e dataset again)")
    t = t[t["status"] == "failed"]
    return {r.scene_id: f"{stage_label(r.failed_stage)}: {r.reason}" for r in t.itertuples()}


def status_line(table: pd.DataFrame, max_listed: int = 10) -> str:
    """The line ``gs2e dataset`` ends with: how many scenes passed, how many
    failed, and each failed scene's stage and reason (the first ``max_listed``;
    the status table has them all)."""
    n = len(table)
    failed = table[table["status"] == "failed"]
    if failed.empty:
        return f"dataset: all {n} scenes passed"
    why = "; ".join(f"{r.scene_id} ({stage_label(r.failed_stage)}: {r.reason})"
                    for r in failed.head(max_listed).itertuples())
    if len(failed) > max_listed:
        why += f"; and {len(failed) - max_listed} more (scene_status.parquet)"
    return f"dataset: {n - len(failed)} of {n} scenes passed, {len(failed)} failed: {why}"
