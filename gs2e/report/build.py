"""Assemble the HTML report of a results tree (what ``gs2e report`` runs)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from gs2e import __version__
from gs2e.common.errors import InputError
from gs2e.common.log import timed
from gs2e.common.progress import progress
from gs2e.common.settings import require
from gs2e.report import html as H
from gs2e.report import io as R
from gs2e.report import plots as P
from gs2e.report.settings import MetricsSettings

log = logging.getLogger("gs2e.report")

# Overview columns (those present are shown, in this order).
OVERVIEW_COLUMNS = (
    "scene_id", "trajectory", "sfm_n_registered", "sfm_n_views", "sfm_mean_reproj_error_px",
    "train_n_gaussians", "train_iterations", "train_train_time_s", "train_test_psnr",
    "train_test_ssim", "trajectory_duration_us", "render_n_frames", "render_frames_per_s",
    "events_n_events", "events_duration_s", "events_rate_meps", "events_on_fraction",
    "events_iei_median_ms", "events_sampling_step_motion_px_max",
)


def overview_table(summary: pd.DataFrame) -> pd.DataFrame:
    """Key columns of the dataset summary, one row per scene x trajectory."""
    cols = [c for c in OVERVIEW_COLUMNS if c in summary.columns]
    return summary.loc[:, cols].reset_index(drop=True)


def _scene_section(results_dir: Path, scene: str, summary: pd.DataFrame | None,
                   real: P.EventSeries | None, cfg: MetricsSettings) -> list[H.Section]:
    sdir = results_dir / scene
    out = [H.Section(f"Scene {scene}", anchor=f"scene-{scene}")]
    if not sdir.is_dir():
        out[0].add(H.missing(f"results folder {sdir}"))
        return out
    trajs = R.scene_trajectories(sdir, summary, scene)

    cost = H.Section("Stage costs", level=3)
    bench = R.read_benchmarks(sdir / "benchmarks")
    fig = P.benchmark_figure(bench, f"{scene}: per-job cost (Snakemake benchmarks)") if bench is not None else None
    cost.add(H.image(P.fig_png(fig), f"{scene} stage costs") if fig else
             H.missing(f"benchmark tables {sdir / 'benchmarks'}/*.tsv"))

    evs = H.Section("Event statistics", level=3)
    previews = H.Section("Event previews", level=3)
    thumbs = H.Section("Thumbnails", level=3)
    series, notes = [], []
    tpng = sdir / "trajectories" / "trajectories.png"
    thumbs.add(H.image(tpng.read_bytes(), f"{scene} trajectories",
                       "camera trajectories (trajectories/trajectories.png)")
               if tpng.exists() else H.missing(f"trajectory plot {tpng}"))
    window_us = cfg.preview_window_ms * 1e3
    max_side = cfg.thumbnail_max_side_px
    for traj in trajs:
        fdir = sdir / "frames" / traj
        frames = R.read_frames_index(fdir)
        items = []
        if frames is None or len(frames) == 0:
            items.append(H.missing(f"{traj}: frames {fdir / 'frames.parquet'}"))
        else:
            mid = frames.iloc[len(frames) // 2]
            for kind, what in (("rgb", "sharp"), ("blur", "motion-blurred")):
                img = R.read_frame(fdir, kind, str(mid["file"]))
                items.append(H.image(P.image_png(img, max_side), f"{traj} {what}",
                                     f"{traj}: {what} frame {int(mid['frame'])} "
                                     f"(t = {int(mid['t_us']) * 1e-6:.3f} s)")
                             if img is not None else H.missing(f"{traj}: {what} frame {fdir / kind / str(mid['file'])}"))
        thumbs.add(H.gallery(items))

        edir = sdir / "events" / traj
        sim = R.read_sim_events(edir)
        if sim is None:
            evs.add(H.missing(f"{traj}: events {edir / 'events.h5'}"))
            previews.add(H.missing(f"{traj}: events {edir / 'events.h5'}"))
            continue
        ev, shape = sim
        if len(ev) < 2:
            notes.append(H.missing(f"{traj}: fewer than 2 events in {edir / 'events.h5'}"))
            previews.add(H.missing(f"{traj}: events (fewer than 2)"))
            continue
        series.append(P.event_series(ev, shape, f"{traj} {shape[1]}x{shape[0]}"))
        ft = frames["t_us"].to_numpy() if frames is not None and len(frames) else None
        t0, t1, fi = P.preview_window_us(ev, ft, window_us)
        bg = None
        if fi is not None:
            bg = R.read_frame(fdir, "rgb", str(frames.iloc[fi]["file"]))
            if bg is not None and bg.shape[:2] != shape:
                bg = None  # frames rendered at another size than the sensor: grey
        img = P.event_preview(ev, shape, t0, t1, bg)
        on_what = (f"over sharp frame {int(frames.iloc[fi]['frame'])}" if bg is not None
                   else "over grey (no sharp frame)")
        previews.add(H.image(P.image_png(img, max(max_side, 2 * shape[1]) if max_side else None),
                             f"{traj} event preview",
                             f"{traj}: events {t0 * 1e-6:.4f}-{t1 * 1e-6:.4f} s {on_what}; "
                             "blue = net ON, red = net OFF"))
        if (edir / "preview.mp4").exists():
            previews.add(H.paragraph(f"preview video: {scene}/events/{traj}/preview.mp4", "meta"))
    if real is not None:
        series.append(real)
    fig = P.event_stats_figure(series, f"{scene}: simulated events"
                               + (" against the real recording" if real is not None else ""))
    if fig is not None and any(not s.real for s in series):
        evs.blocks.insert(0, H.image(P.fig_png(fig), f"{scene} event statistics",
                                     "rates per pixel and interval densities are normalised "
                                     "so sensors of different size compare"))
    else:
        evs.blocks.insert(0, H.missing(f"simulated events of scene {scene}"))
    evs.blocks.extend(notes)
    return out + [cost, evs, thumbs, previews]


SPEEDS = ("mild", "medium", "strong")


def _base_rows(bench: pd.DataFrame, lit: bool = False) -> pd.DataFrame:
    """The bench table's rows of the base trajectories with a speed preset:
    at the trained radiance only, or (``lit``) under every light as well."""
    keep = bench["trajectory"].astype(str).str.startswith("base_") & bench["preset"].notna()
    if "light" in bench.columns and not lit:
        keep &= bench["light"].isna()
    return bench[keep]


def light_tables(bench: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Per task, the benchmark by light: one row per event model x method,
    one column per speed x lighting condition ("PSNR / SSIM", mean over
    scenes of the base trajectories; ``trained`` = the trained radiance).
    Empty without lit runs."""
    if "light" not in bench.columns or bench["light"].isna().all():
        return {}
    base = _base_rows(bench, lit=True).assign(light=lambda d: d["light"].fillna("trained"))
    out = {}
    for task, g in base.groupby("task", sort=False):
        if "aee_px" in g.columns and g["aee_px"].notna().any():
            continue  # optical flow: not scored in PSNR
        speeds = [p for p in SPEEDS if p in set(g["preset"])] + sorted(set(g["preset"]) - set(SPEEDS))
        lights = ["trained"] + sorted(set(g["light"]) - {"trained"})
        rows = []
        for (model, method), m in g.groupby(["model", "method"], sort=False):
            row = {"events": model, "method": method}
            for sp in speeds:
                for li in lights:
                    v = m[(m["preset"] == sp) & (m["light"] == li)]
                    row[f"{sp} {li}"] = f"{v['psnr'].mean():.2f} / {v['ssim'].mean():.3f}" if len(v) else None
            rows.append(row)
        out[str(task)] = pd.DataFrame(rows)
    return out


def bench_tables(bench: pd.DataFrame) -> dict[str, pd.DataFrame]:
    """Per task, the paper's layout: one row per event model x method, one
    column per speed preset ("PSNR / SSIM", or for optical flow "AEE px /
    share over 3 px", mean over scenes of the base trajectories), plus the
    blur's median motion over the exposure (px)."""
    out = {}
    for task, g in _base_rows(bench).groupby("task", sort=False):
        speeds = [p for p in SPEEDS if p in set(g["preset"])] + sorted(set(g["preset"]) - set(SPEEDS))
        is_flow = "aee_px" in g.columns and g["aee_px"].notna().any()
        rows = []
        for (model, method), m in g.groupby(["model", "method"], sort=False):
            row = {"events": model, "method": method}
            for sp in speeds:
                v = m[m["preset"] == sp]
                if not len(v):
                    row[sp] = None
                elif is_flow:
                    row[sp] = f"{v['aee_px'].mean():.2f} px / {v['out_3px'].mean():.1%}"
                else:
                    row[sp] = f"{v['psnr'].mean():.2f} / {v['ssim'].mean():.3f}"
            rows.append(row)
        motion = {"events": "", "method": "motion over the exposure (px, median)"}
        for sp in speeds:
            v = g[g["preset"] == sp]["motion_px_median"]
            motion[sp] = f"{v.mean():.1f}" if v.notna().any() else None
        extra = []
        if "cpu_min" in g.columns and g["cpu_min"].notna().any():  # recon3d: training cost
            for method, m in g.groupby("method", sort=False):
                cost = {"events": "", "method": f"{method}: CPU-minutes"}
                for sp in speeds:
                    v = m[m["preset"] == sp]["cpu_min"]
                    cost[sp] = f"{v.mean():.1f}" if v.notna().any() else None
                extra.append(cost)
            held = {"events": "", "method": "held-out frames (fewest of a scene's)"}
            for sp in speeds:
                v = g[g["preset"] == sp]["n_frames"]
                held[sp] = f"{int(v.min())}" if v.notna().any() else None
            extra.append(held)
        out[str(task)] = pd.DataFrame(rows + [motion] + extra)
    return out


def real_vs_synthetic(bench: pd.DataFrame | None, real: pd.DataFrame) -> pd.DataFrame:
    """Video reconstruction, one row per method: "PSNR / SSIM" on gs2e's base
    trajectories per speed (the video task, mean over scenes and event models)
    beside each real recording's (its APS frames; PSNR pooled over the frames,
    as the bench table pools it)."""
    video = None
    if bench is not None and len(bench):
        base = _base_rows(bench)
        video = base[base["task"] == "video"]
    speeds = ([p for p in SPEEDS if p in set(video["preset"])] if video is not None else [])
    recs = list(dict.fromkeys(real["recording"].astype(str)))
    methods = list(dict.fromkeys(list(video["method"]) if video is not None else [])) + \
        [m for m in dict.fromkeys(real["method"]) if video is None or m not in set(video["method"])]
    rows = []
    for m in methods:
        row = {"method": m}
        for sp in speeds:
            v = video[(video["method"] == m) & (video["preset"] == sp)]
            row[f"gs2e {sp}"] = f"{v['psnr'].mean():.2f} / {v['ssim'].mean():.3f}" if len(v) else None
        for rec in recs:
            v = real[(real["recording"] == rec) & (real["method"] == m)]
            if len(v):
                mse = float(v["mse"].mean())
                psnr = -10.0 * np.log10(mse) if mse > 0 else float("inf")
                row[f"real {rec}"] = f"{psnr:.2f} / {v['ssim'].mean():.3f}"
            else:
                row[f"real {rec}"] = None
        rows.append(row)
    return pd.DataFrame(rows)


def _real_video_part(sec: H.Section, bench: pd.DataFrame | None, real: pd.DataFrame) -> None:
    sec.add(H.paragraph("Video reconstruction on real events with real frames (bench.real_video, "
                        "gs2e bench-real) beside gs2e's trajectories: PSNR (dB) / SSIM against the "
                        "recordings' APS frames, every frame after the first reconstructed from the "
                        "events; integration and the complementary filter start from the first APS "
                        "frame with a nominal contrast (bench.real_video_theta), the learned networks "
                        "from events alone; keyframe_held is the first frame itself, the reference the "
                        "events must beat. Columns gs2e <speed>: the video task above."))
    sec.add(H.table(real_vs_synthetic(bench, real)))


def sim2real_table(dist: pd.DataFrame) -> pd.DataFrame:
    """One row per metric, one column per variant: "distance (floor)"; the
    real recording's and the best variant's values beside."""
    rows = []
    variants = list(dict.fromkeys(dist["variant"].astype(str)))
    for metric, g in dist.groupby("metric", sort=False):
        g = g.set_index("variant")
        row = {"metric": metric, "real": g["real"].iloc[0]}
        for v in variants:
            if v in g.index:
                d, f = g.at[v, "distance"], g.at[v, "floor"] if "floor" in g.columns else np.nan
                row[v] = None if pd.isna(d) else f"{d:.3f} ({f:.3f})" if pd.notna(f) else f"{d:.3f}"
        best = g["distance"].astype(float)
        row["closest"] = best.idxmin() if best.notna().any() else None
        rows.append(row)
    return pd.DataFrame(rows)


def _sim2real_part(sec: H.Section, results_dir: Path, scenes: list[str]) -> None:
    found = False
    for scene in scenes:
        folder = results_dir / scene / "sim2real"
        dist = R.read_sim2real(folder)
        if dist is None:
            continue
        found = True
        sec.add(H.paragraph(f"Sim-to-real on {scene} (bench.sim2real, gs2e bench-sim2real): the scene "
                            "rebuilt from the recording's own frames and poses, simulated along the "
                            "recorded camera path and compared with the real events over the same time. "
                            "Each cell: the distance to the real events (0 = the same), in brackets "
                            "its floor, the variant's distance to itself at another seed (no "
                            "simulation with threshold mismatch gets closer to a real sensor's own "
                            "mismatch map than about that). count_ratio |log N_sim/N_real|; "
                            "on_fraction, edge_fraction absolute differences; count_corr(_pooled) "
                            "1 - Pearson r of per-pixel counts per window (pooled 4x4); count_l1, "
                            "rate_l1 L1 after matching the totals (2 = disjoint); iei_w1 "
                            "1-Wasserstein distance of log10 inter-event intervals (decades). "
                            "See gs2e.bench.sim2real."))
        sec.add(H.table(sim2real_table(dist)))
        png = folder / "sim2real.png"
        if png.is_file():
            sec.add(H.image(png.read_bytes(), f"{scene} sim-to-real",
                            f"{scene}: real and simulated events, one window each, and the rates"))
    if not found:
        sec.add(H.paragraph("Not run here: sim-to-real on a real recording of a scene (bench.sim2real "
                            "is not set for any scene; make sim2real runs it on slider_depth).", "meta"))


def _by_speed(path: Path) -> tuple:
    """Sort key of a per-trajectory example strip (bench/<task>/<trajectory>.png):
    the speed presets in order (mild, medium, strong), then the name, then the
    task, so each speed's deblurring (EDI) and video (PIE-Net) crops sit side by side."""
    rank = next((i for i, sp in enumerate(SPEEDS) if sp in path.stem), len(SPEEDS))
    return rank, path.stem, path.parent.name


def _bench_section(results_dir: Path, scenes: list[str]) -> H.Section:
    sec = H.Section("Benchmark: deblurring, video and 3D reconstruction, optical flow", anchor="bench")
    bench = R.read_bench(results_dir)
    real = R.read_bench_real(results_dir)
    if bench is None or len(bench) == 0:
        sec.add(H.missing(f"benchmark table {results_dir / 'bench.parquet'} (bench.tasks is empty)"))
        if real is not None and len(real):
            _real_video_part(sec, None, real)
        return sec
    bench = bench[bench["scene_id"].astype(str).isin(scenes)]
    sec.add(H.paragraph("PSNR (dB) / SSIM against the sharp frames, mean over scenes, base "
                        "trajectories at each speed; deblur in colour, video on luminance (events "
                        "carry no colour), video frames reconstructed from events alone after the "
                        "first frame. edi_oracle uses the simulator's threshold; edi_chosen, no "
                        "oracle, the one per frame under which consecutive blurred frames agree. "
                        "pienet / pienet_lite: the learned PIE-Net networks, from events alone (they "
                        "never see the first frame), scored after EVREAL's robust normalisation; "
                        "keyframe_held, the first frame itself, is the reference the events must beat. "
                        "recon3d (the paper's Table 1): 3DGS trained from the trajectory's events "
                        "(event_only), events and blurred frames (event_blur) or sharp frames "
                        "(sharp), scored on luminance at held-out poses after a per-image affine "
                        "correction of log luminance (gs2e.bench.recon3d). flow: optical flow "
                        "between consecutive frames from their events alone, average endpoint error "
                        "(px) / share of pixels over 3 px against the ground truth of depth and poses "
                        "(valid pixels only); zero is the floor, contrast_max maximises the contrast "
                        "of warped events (gs2e.bench.flow)."))
    tables = bench_tables(bench)
    for task, tab in tables.items():
        sec.add(H.paragraph(f"task: {task}", "meta"))
        sec.add(H.table(tab))
    by_light = light_tables(bench)
    if by_light:
        sec.add(H.paragraph("By light (runs <trajectory>@<condition>, light.runs): the same tasks at each "
                            "speed under each lighting condition, PSNR / SSIM, mean over scenes; trained = "
                            "the trained radiance (no condition). Frames through render.camera; events "
                            "under the same light (docs/light.md)."))
        for task, tab in by_light.items():
            sec.add(H.paragraph(f"task: {task}, by light", "meta"))
            sec.add(H.table(tab))
    # the schema's task list (held equal to gs2e.bench.tasks by a test): importing the
    # registry would tie the report's code version to every task's code
    from gs2e.config import load_schema

    tasks = load_schema()["properties"]["bench"]["properties"]["tasks"]["items"]["enum"]
    not_run = [t for t in tasks if t not in set(bench["task"].astype(str))]
    if not_run:
        sec.add(H.paragraph(f"Not run here: {', '.join(not_run)} (not in bench.tasks; see "
                            "docs/bench.md for each task and its cost).", "meta"))
    if real is not None and len(real):
        _real_video_part(sec, bench, real)
    else:
        sec.add(H.paragraph("Not run here: video reconstruction on real recordings with APS frames "
                            "(bench.real_video is empty).", "meta"))
    items = []
    for scene in scenes:
        for png in sorted((results_dir / scene / "bench").glob("*/*.png"), key=_by_speed):
            items.append(H.image(png.read_bytes(), f"{scene} {png.parent.name} {png.stem}",
                                 f"{scene}: {png.parent.name} on {png.stem}"))
    if items:
        sec.add(H.gallery(items))
    cols = [c for c in ("scene_id", "trajectory", "light", "task", "model", "method", "n_frames", "psnr",
                        "ssim", "motion_px_median", "psnr_at_0_5s", "psnr_end", "drift_db_per_s",
                        "psnr_raw", "psnr_rgb", "psnr_rgb_corrected", "cpu_min", "aee_px", "out_3px", "aee_px_events",
                        "time_s_per_frame") if c in bench.columns]
    sec.add(H.table(bench.loc[:, cols].reset_index(drop=True)))
    return sec


def _card_section(results_dir: Path, summary: pd.DataFrame | None) -> H.Section:
    """The dataset page: one row per scene (status, views, registered views,
    held-out PSNR/SSIM, Gaussians, events, CPU) and the distributions across
    scenes (:mod:`gs2e.dataset.card`)."""
    from gs2e.dataset.card import card_table

    sec = H.Section("Dataset card", anchor="dataset")
    status = R.read_scene_status(results_dir)
    card = card_table(summary, status, R.scene_cpu_min(results_dir))
    if card.empty:
        sec.add(H.missing(f"dataset summary {results_dir / 'summary.parquet'}"))
        return sec
    n_fail = int((card["status"] == "failed").sum())
    sec.add(H.paragraph(f"{len(card)} scene(s): {len(card) - n_fail} passed their quality gates, {n_fail} "
                        "failed (reason per scene; a failed scene is not exported). Units: psnr_db dB, "
                        "cpu_min CPU minutes of all the scene's jobs; events summed over its runs. The "
                        "datasheet: datasheet.md beside this report."))
    sec.add(H.table(card))
    fig = P.card_figure(card)
    if fig is not None:
        sec.add(H.image(P.fig_png(fig), "distributions across scenes",
                        "across scenes: passed filled, failed outlined"))
    return sec


def build_report(results_dir: str | Path, real_events: str | Path | None = None,
                 scenes: list[str] | None = None, cfg: MetricsSettings | None = None,
                 timings: dict[str, float] | None = None) -> str:
    """The HTML report of ``results_dir`` as a string.

    ``real_events``: a real recording to compare event statistics with;
    ``scenes``: restrict to these scene ids (default: all of the summary);
    ``cfg``: the ``metrics`` settings (None: the schema's defaults).
    Missing inputs appear as
    'missing'.
    """
    cfg = MetricsSettings.defaults() if cfg is None else require(cfg, MetricsSettings, "build_report")
    results_dir = Path(results_dir)
    if not results_dir.is_dir():
        raise InputError(f"results folder {results_dir} does not exist")
    timings = {} if timings is None else timings
    with timed("read summary", log, timings):
        summary = R.read_summary(results_dir)
        all_scenes = R.list_scenes(results_dir, summary)
    if scenes:
        unknown = [s for s in scenes if not (results_dir / s).is_dir() and s not in all_scenes]
        if unknown:
            raise InputError(f"{results_dir}: no results for scene(s) {', '.join(unknown)}")
        all_scenes = list(scenes)

    if summary is not None and "status" in summary and not scenes:  # failed scenes: on the card only
        failed = set(summary.loc[summary["status"] == "failed", "scene_id"].astype(str))
        all_scenes = [s for s in all_scenes if s not in failed]
    sections = []
    ov = H.Section("Dataset overview", anchor="overview")
    if summary is None:
        ov.add(H.missing(f"dataset summary {results_dir / 'summary.parquet'}"))
    else:
        sub = summary[summary["scene_id"].astype(str).isin(all_scenes)] if "scene_id" in summary else summary
        ov.add(H.paragraph(f"{len(sub)} trajectories in {len(all_scenes)} scene(s); "
                           "column units are in their names (_s seconds, _us microseconds, "
                           "_px pixels, _meps million events/s, _ms milliseconds, psnr dB)."))
        ov.add(H.table(overview_table(sub)))
    wb = R.read_benchmarks(results_dir / "benchmarks")
    if wb is not None:
        ov.add(H.image(P.fig_png(P.benchmark_figure(wb, "dataset-level jobs")), "dataset-level jobs"))
    sections.append(ov)
    sections.append(_card_section(results_dir, summary))

    with timed("speed against error", log, timings):
        tr = H.Section("Speed against error (training)", anchor="training")
        curves = {s: R.read_curve(results_dir / s) for s in all_scenes}
        fig = P.speed_error_figure(curves)
        tr.add(H.image(P.fig_png(fig), "held-out quality against training time",
                       "held-out views (never trained on); each point is one evaluation")
               if fig else H.missing("training curves (splat/curve.parquet) of every scene"))
        for s, c in curves.items():
            if c is None:
                tr.add(H.missing(f"training curve {results_dir / s / 'splat' / 'curve.parquet'}"))
        sections.append(tr)

    with timed("benchmark", log, timings):
        sections.append(_bench_section(results_dir, all_scenes))

    real = None
    rs = H.Section("Real recording", anchor="real")
    if real_events is None:
        rs.add(H.missing("real recording for comparison (not configured: metrics.real_events / "
                         "--real-events)"))
    else:
        with timed("real recording statistics", log, timings):
            ev, shape, label = R.read_real_events(real_events)
            real = P.event_series(ev, shape, label, real=True)
        st = real.stats
        rs.add(H.paragraph(f"{label}: {st['n_events']} events over {st['duration_s']:.3f} s, "
                           f"{st['rate_meps']:.3g} M events/s, ON fraction {st['on_fraction']:.3f}, "
                           f"median per-pixel inter-event interval {st['iei_median_ms']:.3g} ms. "
                           "Drawn black and dashed in each scene's event statistics."))
    _sim2real_part(rs, results_dir, all_scenes)
    sections.append(rs)

    shown = all_scenes[:cfg.max_scene_sections]
    if len(shown) < len(all_scenes):
        rs.add(H.paragraph(f"Scene sections below: the first {len(shown)} of {len(all_scenes)} "
                           f"scenes (metrics.max_scene_sections); the overview and the training "
                           "curves cover every scene.", "meta"))
    with timed(f"scenes ({len(shown)})", log, timings):
        for scene in progress(shown, desc="report scenes"):
            sections += _scene_section(results_dir, scene, summary, real, cfg)

    # No date in the document: the same results give the same bytes.
    return H.assemble(f"gs2e report: {results_dir}", sections,
                      f"gs2e {__version__}; {len(all_scenes)} scene(s).")


def write_report(path: str | Path, text: str) -> None:
    from gs2e.common.atomic import atomic_file

    with atomic_file(path, "w") as fh:
        fh.write(text)


def n_images(text: str) -> int:
    """Number of embedded images of a report (for logs and tests)."""
    return text.count('src="data:image/png;base64,')
