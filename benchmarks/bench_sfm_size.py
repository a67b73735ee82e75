"""SfM against the size of the image SIFT sees (``sfm.max_image_size``, issue 44).

On the real captures of ../shared/data, ``gs2e sfm`` (incremental mapping,
deterministic: COLMAP on one thread) at several SIFT sizes: views registered,
points, mean reprojection error, camera error against the capture's own poses
where it has them (mouse_colmap: its COLMAP project; temple_ring: Middlebury's
calibration), CPU seconds of extraction, matching and the whole run. The
baseline is the photos' own size (``max_image_size: null``, what ``gs2e sfm``
did before), measured in the same run. Photos already smaller than a size are
unchanged by it, so temple_ring (640 px) and llff_fern (706 px) run once, at
``auto``, to show registration is kept.

    python benchmarks/bench_sfm_size.py [--quick] [--sizes 800,1024,1600,native]

``--quick``: mouse_colmap's first 16 views at ``auto`` and native only.
Writes benchmarks/results/bench_sfm_size.csv and .png; the last printed line
is the headline (mouse_colmap: CPU at ``auto`` against native, views registered).
"""

from __future__ import annotations

import os
import shutil
import sys
import tempfile
from pathlib import Path

import harness
from gs2e.config import load_config
from gs2e.io.ingest import ingest_scene
from gs2e.sfm.colmap_sfm import run_sfm, sift_image_size
from harness import SHARED_SCENES


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


def run_one(scene: str, scene_dir: Path, size, tmp: Path, threads: int) -> dict:
    """``gs2e sfm`` of ``scene_dir`` with SIFT at ``size`` (px, ``auto`` or
    None for the photos' own size): its statistics, wall and CPU seconds of
    this process, all threads (COLMAP runs in-process)."""
    cfg = load_config({})["sfm"]
    cfg["max_image_size"] = size
    out = tmp / f"sfm_{scene}_{size}"
    with harness.clock() as t:
        try:
            st = run_sfm(scene_dir, out, cfg, seed=0, threads=threads)
            err = ""
        except Exception as exc:  # a size too small to register is a result, not a crash
            st, err = {}, str(exc).splitlines()[0][:120]
    cpu, wall = t.cpu_s, t.wall_s
    shutil.rmtree(out, ignore_errors=True)
    return {"scene": scene, "max_image_size": "native" if size is None else size,
            "sift_px": sift_image_size(cfg), "n_views": st.get("n_views"),
            "n_registered": st.get("n_registered"), "n_points": st.get("n_points"),
            "reproj_px": st.get("mean_reproj_error_px"),
            "gt_rot_deg": st.get("gt_rot_median_deg"), "gt_center_pct": st.get("gt_center_rmse_pct_extent"),
            "extraction_s": st.get("time_extraction_s"), "matching_s": st.get("time_matching_s"),
            "mapping_s": st.get("time_mapping_s"), "undistortion_s": st.get("time_undistortion_s"),
            "wall_s": wall, "cpu_s": cpu, "error": err}


def plot(rows: list[dict]) -> Path:
    """CPU seconds and views registered against the SIFT size, per scene, as
    benchmarks/results/bench_sfm_size.png; returns the path."""
    plt = harness.pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.6))
    for scene in sorted({r["scene"] for r in rows}):
        rs = [r for r in rows if r["scene"] == scene]
        x = [r["sift_px"] for r in rs]
        ax[0].plot(x, [r["cpu_s"] for r in rs], "o-", label=scene)
        ax[1].plot(x, [(r["n_registered"] or 0) / (r["n_views"] or 1) for r in rs], "o-", label=scene)
    ax[0].set(xlabel="longer side SIFT sees (px)", ylabel="CPU s (whole gs2e sfm)",
              title="cost against SIFT size")
    ax[1].set(xlabel="longer side SIFT sees (px)", ylabel="views registered (fraction)",
              title="registration", ylim=(0, 1.05))
    ax[0].legend()
    return harness.save_plot(fig, "bench_sfm_size", dpi=110)


def main() -> int:
    ap = harness.parser(__doc__, quick="mouse_colmap's first 16 views, auto and native (a few minutes)")
    ap.add_argument("--sizes", default="800,1024,1600,native",
                    help="comma-separated SIFT sizes for mouse_colmap (px, auto or native)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    os.environ.setdefault("GS2E_PROGRESS", "0")
    if not SHARED_SCENES["mouse_colmap"][1].is_dir():
        print(f"no real data under {SHARED_SCENES['mouse_colmap'][1].parent}; nothing to benchmark")
        return 0
    parse = {"native": None, "auto": "auto"}
    sizes = (["auto", None] if args.quick
             else [parse[s] if s in parse else int(s) for s in args.sizes.split(",")])
    plan = [("mouse_colmap", s) for s in sizes]
    if not args.quick:
        plan += [("temple_ring", "auto"), ("llff_fern", "auto")]
    tmp = Path(tempfile.mkdtemp(prefix="bench_sfm_size_"))
    rows = []
    try:
        ingested = {}
        for scene, size in plan:
            if scene not in ingested:
                layout, src = SHARED_SCENES[scene]
                src = _subset(src, layout, 16 if args.quick else None, tmp)
                layout = "folder" if args.quick else layout
                ingested[scene] = tmp / f"ingest_{scene}"
                ingest_scene(src, layout, ingested[scene], load_config({})["ingest"])
            r = run_one(scene, ingested[scene], size, tmp, args.threads)
            rows.append(r)
            print(f"  {scene:13s} sift {r['sift_px']:5d} px: {r['n_registered']}/{r['n_views']} views, "
                  f"{r['n_points']} points, {r['reproj_px'] or float('nan'):.3f} px, "
                  f"{r['cpu_s']:.1f} CPU-s {r['error']}", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    files = [harness.write_csv("bench_sfm_size", rows), plot(rows)]
    hdr = ("scene", "max_image_size", "sift_px", "n_registered", "n_views", "n_points", "reproj_px",
           "gt_rot_deg", "gt_center_pct", "extraction_s", "matching_s", "mapping_s", "undistortion_s",
           "cpu_s")
    table = ["\n" + " | ".join(hdr)]
    for r in rows:
        table.append(" | ".join("-" if r[k] is None else f"{r[k]:.3g}" if isinstance(r[k], float) else str(r[k])
                                for k in hdr))
    m = {r["max_image_size"]: r for r in rows if r["scene"] == "mouse_colmap"}
    if "auto" in m and "native" in m:
        a, n = m["auto"], m["native"]
        head = (f"headline: mouse_colmap SfM at auto ({a['sift_px']} px) {a['cpu_s']:.0f} CPU-s against "
                f"{n['cpu_s']:.0f} at the photos' size ({n['cpu_s'] / a['cpu_s']:.2f}x less), "
                f"{a['n_registered']}/{a['n_views']} views registered (native {n['n_registered']})")
    else:  # --sizes without both: no ratio to give
        head = "headline: mouse_colmap SfM measured at " + ", ".join(str(s) for s in m) + " (no auto/native pair)"
    harness.report("\n".join(table), head, files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
