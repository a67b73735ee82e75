"""SfM at the size and effort it needs (issue 44): SIFT size, extractor and
bundle adjustment schedule against views registered, camera error and CPU.

On the real captures of ../shared/data, ``gs2e sfm`` (incremental mapping,
deterministic: COLMAP on one thread) in several configurations
(``sfm.max_image_size``, ``sfm.extractor``, ``sfm.bundle_adjustment``,
``sfm.sift_first_octave``, ``sfm.descriptor_matcher``): views
registered, points, mean reprojection error, camera error against the
capture's own poses where it has them (mouse_colmap: its COLMAP project;
temple_ring: Middlebury's calibration), CPU seconds of extraction, matching,
mapping, undistortion and the whole run. The baseline, in the same run, is
what ``gs2e sfm`` did at 783ff0e: the photos' own size, COLMAP's SIFT,
matcher and bundle adjustment schedule and COLMAP's undistorter. Each run also times
COLMAP's undistorter on the same model (``colmap_undistortion_s``) beside
the OpenCV resampling ``gs2e sfm`` now uses (``undistortion_s``). Photos
already smaller than a size are unchanged by it, so temple_ring (640 px) and
llff_fern (706 px) run at ``auto`` only, to show registration is kept.

    python benchmarks/bench_sfm_size.py [--quick] [--configs native:colmap:colmap,auto:colmap:fast,...]
        [--seeds 0,1,2]

A configuration is ``size:extractor:bundle_adjustment[:first_octave[:matcher]]``
(size in px, ``auto`` or ``native``; first octave ``auto``, -1 or 0; matcher
``colmap`` or ``gemm``: ``sfm.descriptor_matcher``). ``--seeds``: the
mapper's seeds for mouse_colmap (a view at the edge of registering registers
under some seeds only). ``--quick``:
mouse_colmap's first 16 views at native and the default only.
``--mouse-side 1440``: mouse_colmap shrunk to a 1080p-class capture first;
``--mouse-16-9 --mouse-views 50``: its first 50 views cropped to 16:9, a
50-view 1080p capture (1920x1080 and 1080x1920 photos).
Writes benchmarks/results/bench_sfm_size[_<variant>].csv and .png; the last printed line
is the headline (mouse_colmap: CPU of the default against the baseline,
views registered).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import harness
import pycolmap
from gs2e.io.ingest import ingest_scene
from gs2e.sfm import colmap_sfm
from gs2e.io.scene import read_scene
from gs2e.sfm.colmap_sfm import run_sfm, sift_max_side_px
from gs2e.sfm.settings import SfmSettings
from harness import SHARED_SCENES


def _derived(src: Path, tmp: Path, side_px: int | None = None, crop_16_9: bool = False,
             n_views: int | None = None) -> Path:
    """mouse_colmap's registered photos (the first ``n_views`` by name), cropped
    about their centre to 16:9 (1920x1440 -> 1920x1080: what a phone's 16:9
    mode keeps of its 4:3 sensor) and/or shrunk (area filter) to a longer side
    of ``side_px``, as a folder scene (no poses)."""
    import cv2

    names = sorted(im.name for im in pycolmap.Reconstruction(str(src / "sparse" / "0")).images.values())
    names = set(names[:n_views])
    out = tmp / f"derived_{src.name}_{side_px}_{'16x9' if crop_16_9 else 'full'}_{n_views}"
    out.mkdir(parents=True, exist_ok=True)
    for f in sorted((src / "images").iterdir()):
        if f.name in names:
            img = cv2.imread(str(f), cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
            h, w = img.shape[:2]
            if crop_16_9:
                long_px, short_px = max(h, w), round(max(h, w) * 9 / 16)
                ch, cw = (short_px, long_px) if w >= h else (long_px, short_px)
                y0, x0 = (h - ch) // 2, (w - cw) // 2
                img = img[y0:y0 + ch, x0:x0 + cw]
                h, w = img.shape[:2]
            if side_px:
                img = cv2.resize(img, (round(w * side_px / max(h, w)), round(h * side_px / max(h, w))),
                                 interpolation=cv2.INTER_AREA)
            cv2.imwrite(str(out / f"{f.stem}.png"), img)
    return out


def _subset(src: Path, layout: str, n_views: int | None, tmp: Path) -> Path:
    """The first ``n_views`` photos of a scene (by name), as a folder scene."""
    if n_views is None:
        return src
    images = src / "images" if layout == "colmap" else src
    out = tmp / f"subset_{src.name}_{n_views}"
    out.mkdir(parents=True, exist_ok=True)
    for f in sorted(p for p in images.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg"))[:n_views]:
        shutil.copy(f, out / f.name)
    return out


# gs2e sfm at 783ff0e: the photos' own size, doubled before SIFT's first octave,
# COLMAP's bundle adjustment schedule and undistorter (its photos are now
# decoded by OpenCV instead of COLMAP's reader: the same SIFT, slightly
# different grey levels)
BASELINE = "native:colmap:colmap:-1:colmap"
DEFAULT = "auto:colmap:fast"  # today's defaults


def parse_config(text: str) -> dict:
    """``size:extractor:bundle_adjustment[:first_octave[:descriptor_matcher]]`` -> sfm config overrides."""
    size, extractor, ba, *rest = text.split(":")
    if len(rest) > 2:
        raise SystemExit(f"configuration {text!r}: at most size:extractor:bundle_adjustment:first_octave:matcher")
    octave, matcher = (rest + ["auto", "colmap"][len(rest):])[:2]
    max_image_size = None if size == "native" else "auto" if size == "auto" else int(size)
    return {"max_image_size": max_image_size, "extractor": extractor, "bundle_adjustment": ba,
            "sift_first_octave": int(octave) if octave != "auto" else "auto", "descriptor_matcher": matcher}


def run_one(scene: str, scene_dir: Path, config: str, seed: int, tmp: Path, threads: int) -> dict:
    """``gs2e sfm`` of ``scene_dir`` in ``config`` with the mapper's ``seed``:
    its statistics (step times: wall seconds, COLMAP's steps on one thread),
    CPU seconds of this process, all threads (COLMAP runs in-process), less
    the CPU of COLMAP's undistorter run beside it on the same model (reported
    apart). The baseline ``config`` uses COLMAP's undistorter itself, as gs2e
    sfm did then."""
    cfg = SfmSettings.defaults(**parse_config(config))
    out = tmp / f"sfm_{scene}_{config.replace(':', '_')}_{seed}"
    ours = colmap_sfm._undistort
    cpu = {"colmap": float("nan"), "ours": float("nan")}

    def undistort_both(model_dir, image_dir, undist, n_threads):
        c0 = time.process_time()
        pycolmap.undistort_images(tmp / "colmap_undist", model_dir, image_dir, num_threads=n_threads)
        cpu["colmap"] = time.process_time() - c0
        if config == BASELINE:  # as gs2e sfm did: COLMAP's views are the output
            shutil.move(str(tmp / "colmap_undist"), str(undist))
            return
        shutil.rmtree(tmp / "colmap_undist")
        c0 = time.process_time()
        ours(model_dir, image_dir, undist, n_threads)
        cpu["ours"] = time.process_time() - c0

    colmap_sfm._undistort = undistort_both
    with harness.clock() as t:
        try:
            st = run_sfm(scene_dir, out, cfg, seed=seed, threads=threads)
            err = ""
        except Exception as exc:  # a size too small to register is a result, not a crash
            st, err = {}, str(exc).splitlines()[0][:120]
        finally:
            colmap_sfm._undistort = ours
    baseline = config == BASELINE
    shutil.rmtree(out, ignore_errors=True)
    return {"scene": scene, "config": config, "seed": seed, "sift_px": sift_max_side_px(cfg, read_scene(scene_dir)),
            "extractor": cfg.extractor, "bundle_adjustment": cfg.bundle_adjustment,
            "n_views": st.get("n_views"), "n_registered": st.get("n_registered"), "n_points": st.get("n_points"),
            "reproj_px": st.get("mean_reproj_error_px"),
            "gt_rot_deg": st.get("gt_rot_median_deg"), "gt_center_pct": st.get("gt_center_rmse_pct_extent"),
            "extraction_s": st.get("time_extraction_s"), "matching_s": st.get("time_matching_s"),
            "descriptor_matching_s": st.get("time_descriptor_matching_s"), "verification_s": st.get("time_verification_s"),
            "mapping_s": st.get("time_mapping_s"),
            "undistortion_cpu_s": cpu["colmap"] if baseline else cpu["ours"], "colmap_undistortion_cpu_s": cpu["colmap"],
            "wall_s": t.wall_s, "cpu_s": t.cpu_s - (0.0 if baseline else cpu["colmap"]), "error": err}


def plot(rows: list[dict], name: str = "bench_sfm_size") -> Path:
    """CPU seconds (by step) and views registered per configuration on
    mouse_colmap, as benchmarks/results/bench_sfm_size.png; returns the path."""
    import numpy as np

    plt = harness.pyplot()
    rs = [r for r in rows if r["scene"] == "mouse_colmap" and not r["error"]]
    configs = list(dict.fromkeys(r["config"] for r in rs))
    steps = ("extraction_s", "matching_s", "mapping_s", "undistortion_cpu_s")
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    bottom = np.zeros(len(configs))
    for step in steps:
        v = np.array([np.mean([r[step] or 0.0 for r in rs if r["config"] == c]) for c in configs])
        ax[0].bar(range(len(configs)), v, bottom=bottom, label=step.split("_")[0])
        bottom += v
    ax[0].plot(range(len(configs)), [np.mean([r["cpu_s"] for r in rs if r["config"] == c]) for c in configs],
               "k_", ms=30, label="whole gs2e sfm")
    ax[0].set_xticks(range(len(configs)), configs, rotation=15, fontsize=7)
    ax[0].set(ylabel="s (mean over seeds)", title="mouse_colmap: steps (s) and whole run (CPU s)")
    ax[0].legend(fontsize=7)
    for i, c in enumerate(configs):
        reg = [r["n_registered"] for r in rs if r["config"] == c]
        ax[1].plot([i] * len(reg), reg, "o", alpha=0.6)
    ax[1].set_xticks(range(len(configs)), configs, rotation=15, fontsize=7)
    n_views = rs[0]["n_views"] if rs else 1
    ax[1].set(ylabel="views registered (each seed)", title=f"registration of {n_views} views",
              ylim=(n_views - 4.5, n_views + 0.5))
    return harness.save_plot(fig, name, dpi=110)


def main() -> int:
    ap = harness.parser(__doc__, quick="mouse_colmap's first 16 views, baseline and default (a few minutes)")
    ap.add_argument("--configs", default=f"{BASELINE},{DEFAULT},auto:colmap:fast:auto:gemm",
                    help="comma-separated size:extractor:bundle_adjustment[:first_octave[:matcher]] for mouse_colmap")
    ap.add_argument("--seeds", default="0,1,2", help="mapper seeds for mouse_colmap")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--mouse-side", type=int, default=None,
                    help="shrink mouse_colmap's photos to this longer side first (e.g. 1440: a 1080p-class "
                         "capture; folder layout, so no camera errors)")
    ap.add_argument("--mouse-16-9", action="store_true",
                    help="crop mouse_colmap's photos about their centre to 16:9 first (1920x1080 and 1080x1920: "
                         "a phone's 16:9 mode; folder layout)")
    ap.add_argument("--mouse-views", type=int, default=None,
                    help="mouse_colmap's first this many registered views only (folder layout)")
    ap.add_argument("--no-small", action="store_true", help="skip temple_ring and llff_fern")
    args = ap.parse_args()
    os.environ.setdefault("GS2E_PROGRESS", "0")
    if args.quick and (args.mouse_side or args.mouse_16_9 or args.mouse_views):
        ap.error("--quick takes mouse_colmap's first 16 photos as they are: no --mouse-side, --mouse-16-9, --mouse-views")
    if not SHARED_SCENES["mouse_colmap"][1].is_dir():
        print(f"no real data under {SHARED_SCENES['mouse_colmap'][1].parent}; nothing to benchmark")
        return 0
    configs = [BASELINE, DEFAULT] if args.quick else args.configs.split(",")
    seeds = [0] if args.quick else [int(x) for x in args.seeds.split(",")]
    plan = [("mouse_colmap", c, seed) for c in configs for seed in (seeds if c != BASELINE else seeds[:1])]
    if not args.quick and not args.no_small:
        plan += [(scene, c, 0) for scene in ("temple_ring", "llff_fern") for c in (BASELINE, DEFAULT)]
    tmp = Path(tempfile.mkdtemp(prefix="bench_sfm_size_"))
    rows = []
    try:
        ingested = {}
        for scene, config, seed in plan:
            if scene not in ingested:
                layout, src = SHARED_SCENES[scene]
                src = _subset(src, layout, 16 if args.quick else None, tmp)
                layout = "folder" if args.quick else layout
                if scene == "mouse_colmap" and (args.mouse_side or args.mouse_16_9 or args.mouse_views):
                    src, layout = _derived(src, tmp, args.mouse_side, args.mouse_16_9, args.mouse_views), "folder"
                ingested[scene] = tmp / f"ingest_{scene}"
                ingest_scene(src, layout, ingested[scene])
            r = run_one(scene, ingested[scene], config, seed, tmp, args.threads)
            rows.append(r)
            print(f"  {scene:13s} {config:22s} seed {seed}: {r['n_registered']}/{r['n_views']} views, "
                  f"{r['n_points']} points, {r['reproj_px'] or float('nan'):.3f} px, "
                  f"{r['cpu_s']:.1f} CPU-s {r['error']}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    name = "bench_sfm_size" + (f"_{args.mouse_side}px" if args.mouse_side else "") + \
        ("_16x9" if args.mouse_16_9 else "") + (f"_{args.mouse_views}views" if args.mouse_views else "")
    files = [harness.write_csv(name, rows), plot(rows, name)]
    hdr = ("scene", "config", "seed", "sift_px", "n_registered", "n_views", "n_points", "reproj_px",
           "gt_rot_deg", "gt_center_pct", "extraction_s", "matching_s", "mapping_s", "undistortion_cpu_s",
           "colmap_undistortion_cpu_s", "cpu_s")
    table = ["\n" + " | ".join(hdr)]
    for r in rows:
        table.append(" | ".join("-" if r[k] is None else f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k])
                                for k in hdr))
    m = [r for r in rows if r["scene"] == "mouse_colmap"]
    base = [r for r in m if r["config"] == BASELINE]
    dflt = [r for r in m if r["config"] == DEFAULT]
    if base and dflt:
        cpu = sum(r["cpu_s"] for r in dflt) / len(dflt)
        head = (f"headline: mouse_colmap SfM with the defaults ({DEFAULT}) {cpu:.0f} CPU-s against "
                f"{base[0]['cpu_s']:.0f} for 783ff0e's ({BASELINE}; {base[0]['cpu_s'] / cpu:.2f}x less), "
                f"views registered {'/'.join(str(r['n_registered']) for r in dflt)} of {dflt[0]['n_views']} "
                f"over seeds (783ff0e's: {base[0]['n_registered']})")
    else:
        head = "headline: mouse_colmap SfM measured in " + ", ".join(dict.fromkeys(r["config"] for r in m)) + \
            f" (no {BASELINE} / {DEFAULT} pair)"
    harness.report("\n".join(table), head, files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
