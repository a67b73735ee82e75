"""The dataset's card: one row per scene (what the report's dataset page and the
datasheet show) and the datasheet itself.

The datasheet answers the questions of "Datasheets for Datasets" (Gebru et al.,
CACM 64(12), 2021; arXiv:1803.09010) that a run can answer: what the dataset
holds, where each scene came from and under which terms, how it was made
(settings, gates), what failed and why, and what it is for. Each scene's
source and terms are read from its input folder (:func:`provenance`), never
typed in; where a folder states none, the datasheet says so.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pandas as pd

from gs2e.common.settings import require
from gs2e.dataset.settings import DatasetSettings
from gs2e.dataset.status import stage_label

# Per-scene columns of the card, in order (units in the names: CPU minutes,
# dB; counts otherwise).
CARD_COLUMNS = ("scene_id", "status", "views", "registered", "psnr_db", "ssim", "gaussians",
                "events", "cpu_min", "reason")
_SOURCE_KEYS = {"source": ("source", "origin"), "terms": ("license", "licence", "terms")}


def _first_value(text: str, keys: tuple[str, ...]) -> str | None:
    for line in text.splitlines():
        k, sep, v = line.partition(":")
        if sep and k.strip().lower() in keys and v.strip():
            return v.strip()
    return None


def _sources_md_row(sources_md: Path, scene_path: Path) -> dict | None:
    """The row of a data folder's SOURCES.md table (``| folder/ | what | origin | terms |``)
    naming ``scene_path`` (or a folder above it)."""
    try:
        rel = scene_path.resolve().relative_to(sources_md.parent.resolve()).as_posix()
        lines = sources_md.read_text(errors="replace").splitlines()
    except (ValueError, OSError):
        return None
    best = None
    for line in lines:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 4:
            continue
        folder = cells[0].strip("`").rstrip("/")
        if folder and (rel == folder or rel.startswith(folder + "/")):
            if best is None or len(folder) > len(best[0]):
                best = (folder, cells)
    if best is None:
        return None
    cells = best[1]
    return {"source": cells[-2], "terms": cells[-1], "from": str(sources_md)}


def provenance(path: str | Path | None, max_up: int = 3) -> dict:
    """Where a scene's input came from and under which terms, read from its folder.

    Looks in the folder and up to ``max_up`` folders above it for, in order:
    a ``SOURCE.txt`` (its ``source:`` and ``license:`` lines), a ``LICENSE*`` /
    ``README*`` file (terms: the licence's first line), a ``SOURCES.md`` whose
    table has a row for the folder (its origin and terms columns).

    Returns
    -------
    dict with ``source``, ``terms`` and ``from`` (the file read); the values
    are None where no file states them (a generated scene, a folder without
    any of these files).
    """
    out = {"source": None, "terms": None, "from": None}
    if not path:
        return out
    p = Path(path)
    folders = [p] + list(p.parents)[:max_up]
    found = []  # what each file states, in the order above; the first to state a field wins
    for d in folders:
        f = d / "SOURCE.txt"
        if f.is_file():
            text = f.read_text(errors="replace")
            found.append({"source": _first_value(text, _SOURCE_KEYS["source"]),
                          "terms": _first_value(text, _SOURCE_KEYS["terms"]), "from": str(f)})
            break
        lic = sorted(d.glob("LICENSE*")) + sorted(d.glob("LICENCE*"))
        readme = sorted(d.glob("README*"))
        if lic or readme:
            found.append({"source": _first_line(readme[0]) if readme else None,
                          "terms": _first_line(lic[0]) if lic else None, "from": str((lic or readme)[0])})
            break
    for d in folders:
        f = d / "SOURCES.md"
        if f.is_file() and (row := _sources_md_row(f, p)):
            found.append(row)
            break
    froms = []
    for f in found:
        for k in ("source", "terms"):
            if out[k] is None and f[k]:
                out[k] = f[k]
                froms.append(f["from"])
    out["from"] = ", ".join(dict.fromkeys(froms)) or None
    return out


def _first_line(path: Path) -> str | None:
    lines = [ln.strip("# ").strip() for ln in path.read_text(errors="replace").splitlines() if ln.strip()]
    return lines[0] if lines else None


def card_table(summary: pd.DataFrame, status: pd.DataFrame | None, cpu_min: dict[str, float]) -> pd.DataFrame:
    """One row per scene (:data:`CARD_COLUMNS`): its status and reason, views
    ingested and registered, held-out PSNR (dB) and SSIM, Gaussians, events
    summed over its runs and CPU minutes. Values a scene does not have are NaN."""
    def col(df, name):
        return df[name] if name in df.columns else pd.Series(np.nan, index=df.index)

    rows = {}
    if summary is not None and len(summary):
        for sid, g in summary.groupby("scene_id", sort=False):
            rows[sid] = {
                "scene_id": sid,
                "status": g["status"].iloc[0] if "status" in g else "passed",
                "views": col(g, "sfm_n_views").iloc[0], "registered": col(g, "sfm_n_registered").iloc[0],
                "psnr_db": col(g, "train_test_psnr").iloc[0], "ssim": col(g, "train_test_ssim").iloc[0],
                "gaussians": col(g, "train_n_gaussians").iloc[0],
                "events": pd.to_numeric(col(g, "events_n_events"), errors="coerce").sum(min_count=1),
                "reason": g["fail_reason"].iloc[0] if "fail_reason" in g else None}
    if status is not None:
        for r in status.itertuples():
            row = rows.setdefault(r.scene_id, {"scene_id": r.scene_id})
            row["status"] = r.status
            row["reason"] = f"{stage_label(r.failed_stage)}: {r.reason}" if r.status == "failed" else None
            for k, v in (("views", r.n_views), ("registered", r.n_registered), ("psnr_db", r.test_psnr_db),
                         ("ssim", r.test_ssim), ("gaussians", r.n_gaussians), ("events", r.n_events)):
                if pd.isna(row.get(k, np.nan)):
                    row[k] = v
    for sid, row in rows.items():
        row["cpu_min"] = cpu_min.get(sid, np.nan)
    return pd.DataFrame(list(rows.values()), columns=list(CARD_COLUMNS))


def _fmt(v, spec: str = "{:.2f}") -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "missing"
    return spec.format(v)


def _dist(values: pd.Series, spec: str) -> str:
    v = pd.to_numeric(values, errors="coerce").dropna()
    if v.empty:
        return "missing"
    return (f"median {spec.format(v.median())}, min {spec.format(v.min())}, max {spec.format(v.max())} "
            f"({len(v)} scenes)")


def datasheet_markdown(card: pd.DataFrame, sources: dict[str, dict], settings: DatasetSettings,
                       title: str = "gs2e dataset") -> str:
    """The datasheet (Markdown) of a dataset from its card and its scenes' sources.

    ``sources``: {scene id: {layout, path, source, terms, from}} (the scenes
    table and :func:`provenance`). No date, host or CPU time in the text: the
    same data gives the same bytes.
    """
    cfg = require(settings, DatasetSettings, "datasheet_markdown")
    passed = card[card["status"] == "passed"]
    failed = card[card["status"] == "failed"]
    gates = [f"`{k}` = {v:g}" for k, v in cfg.as_dict().items() if v is not None] or ["none set"]
    L = [f"# Datasheet: {title}", "",
         "Questions after Gebru et al., *Datasheets for Datasets* (CACM 64(12), 2021). Written by "
         "`gs2e datasheet` from the run's own tables; a value the run did not measure reads *missing*.", "",
         "## Motivation", "",
         "- **For what purpose was the dataset created?** Training and benchmarking event-vision methods "
         "(deblurring, video reconstruction, event-based 3D reconstruction) with exact ground truth: "
         "synthetic event streams, sharp and motion-blurred frames, poses, depth, optical flow and IMU "
         "rendered from 3D Gaussian Splatting models of real captures (the GS2E method).",
         "- **Who created it?** Whoever ran this gs2e workflow; the captures' authors are listed below.", "",
         "## Composition", "",
         f"- **What do the instances represent?** {len(card)} static real scenes, each seen along virtual "
         "camera paths; per path: events (HDF5), frames, poses and ground truth.",
         f"- **How many instances?** {len(passed)} scenes passed every quality gate; {len(failed)} failed "
         "and are not part of the good set (reasons below).",
         f"- **Held-out PSNR of the models:** {_dist(passed['psnr_db'], '{:.2f} dB')}; SSIM "
         f"{_dist(passed['ssim'], '{:.3f}')}.",
         f"- **Events per scene:** {_dist(passed['events'], '{:.3g}')}.",
         f"- **Is anything missing?** {len(failed)} scene(s) failed: "
         + ("; ".join(f"`{r.scene_id}` ({r.reason})" for r in failed.itertuples()) if len(failed) else "none")
         + ".",
         "- **Does it contain people or sensitive data?** The inputs are photos of objects and places; a "
         "scene-level capture may show passers-by (see each source). Nothing is inferred about anyone.", "",
         "### Scenes", "",
         "| scene | status | views | registered | PSNR dB | SSIM | Gaussians | events | source | terms |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for r in card.itertuples():
        s = sources.get(r.scene_id, {})
        L.append(f"| {r.scene_id} | {r.status} | {_fmt(r.views, '{:.0f}')} | {_fmt(r.registered, '{:.0f}')} | "
                 f"{_fmt(r.psnr_db)} | {_fmt(r.ssim, '{:.3f}')} | {_fmt(r.gaussians, '{:.0f}')} | "
                 f"{_fmt(r.events, '{:.3g}')} | "
                 f"{_cell(s.get('source')) or 'not stated in the input folder'} | "
                 f"{_cell(s.get('terms')) or 'not stated in the input folder'} |")
    L += ["", "## Collection process", "",
          "- **How was the data acquired?** The photos were taken by the captures' authors (sources "
          "above). gs2e ingested them (layout per scene below), recovered cameras with COLMAP where none "
          "came with the capture, trained a 3DGS model per scene on the CPU and rendered and simulated "
          "along smooth virtual paths at three speeds.",
          "- **Layouts and input folders:**", ""]
    for sid, s in sources.items():
        L.append(f"  - `{sid}`: {s.get('layout')} `{s.get('path') or '(generated)'}`"
                 + (f" (source and terms read from `{s['from']}`)" if s.get("from") else ""))
    L += ["", "## Preprocessing, cleaning, labelling", "",
          f"- **Quality gates** (config `dataset`): {', '.join(gates)}. A scene below a gate, or whose "
          "structure from motion or training failed, is recorded with a one-line reason "
          "(`scene_status.parquet`, `summary.parquet`, the report) and its exports are not made.",
          "- **Cost:** CPU time per scene and stage is on the report's dataset card (`report.html`); it "
          "is left out here so that the same data gives the same datasheet.", "",
          "## Uses", "",
          "- **Intended:** research on event cameras: training and evaluating deblurring, video "
          "reconstruction, optical flow and event-based 3D reconstruction.",
          "- **Not suited for:** claims about a real sensor's exact noise without calibration against it; "
          "any use the source terms exclude (several captures are non-commercial).", "",
          "## Distribution", "",
          "- **Terms:** each scene keeps its source's terms (table above); the derived data is not more "
          "permissive than its input. Scenes whose folder states no terms must be cleared with their "
          "authors before redistribution.", "",
          "## Maintenance", "",
          "- **Regenerate:** `make dataset` (the same config gives the same bytes). Fix or drop a failed "
          "scene in the scenes table and run it again: only that scene's jobs run.", ""]
    return "\n".join(L)


def _cell(text: str | None) -> str | None:
    return re.sub(r"\s+", " ", text.replace("|", "/")).strip() if text else None


def write_datasheet(summary_path: str | Path, status_path: str | Path | None, scenes: list[dict],
                    settings: DatasetSettings, out: str | Path) -> None:
    """Write ``out`` (datasheet.md, atomically) from a run's summary, status
    table (optional) and scenes (the scenes table's rows: scene_id, layout,
    path). Nothing measured in time goes in (no date, host or CPU time): the
    same data gives the same bytes.

    Raises InputError naming the summary or status table when it is absent."""
    from gs2e.common.atomic import atomic_file
    from gs2e.common.errors import InputError

    for what, path in (("summary", summary_path), ("status table", status_path)):
        if path is not None and not Path(path).is_file():
            raise InputError(f"{path}: the {what} does not exist (the workflow writes it before the datasheet)")
    summary = pd.read_parquet(summary_path)
    status = pd.read_parquet(status_path) if status_path else None
    card = card_table(summary, status, {})
    sources = {}
    for row in scenes:
        path = row.get("path")
        sources[row["scene_id"]] = {"layout": row["layout"], "path": path, **provenance(path)}
    with atomic_file(out, "w") as fh:
        fh.write(datasheet_markdown(card, sources, settings))
