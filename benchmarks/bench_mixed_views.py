"""Views of mixed orientation: each at its own size against squeezed into one.

``../shared/data/mouse_colmap`` is a real phone capture with a COLMAP model:
landscape (1920x1440) and portrait (1440x1920) views, one camera per image.
gs2e keeps every view at its own size and orientation through ingest, SfM,
training and evaluation ("own size"). The baseline, measured in the same run,
is what ``ingest.allow_mixed_resolutions`` did before: every view resized to
the first view's landscape grid with its intrinsics rescaled anisotropically
("squeezed"). Both train with the workflow's defaults at the size that covers
the event sensor (``--sensor``, default davis346), from the capture's own
cameras and points (``sfm.reuse_poses``), same seed.

Also checked: the ``mvimgnet`` layout of the same capture ingests to the same
views, sizes and cameras as ``colmap``.

Usage: python benchmarks/bench_mixed_views.py [--quick] [--sensor davis346|imx636] [--work DIR]

``--quick``: only the ingest check (mvimgnet against colmap; the ingested
scenes are cached in ``--work``), no SfM or training, nothing written.

Writes benchmarks/results/bench_mixed_views.csv (one row per held-out view),
bench_mixed_views.json (per variant) and bench_mixed_views.png; the last
printed line is the headline.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path

os.environ.setdefault("GS2E_PROGRESS", "0")

# first: importing gs2e sets OMP_WAIT_POLICY before torch loads
from gs2e.config import load_section  # noqa: E402
from gs2e.events.settings import event_settings

import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

import harness  # noqa: E402
from harness import RESULTS  # noqa: E402

DATA = harness.SHARED


def squeezed_copy(scene_dir: Path, out: Path) -> None:
    """``scene_dir`` with every view resized to the scene's own size (the
    pre-0.2 ``allow_mixed_resolutions``): portrait views squeezed into the
    landscape grid, intrinsics scaled per axis."""
    from gs2e.io.images import read_image, resize_with_camera, write_png
    from gs2e.io.scene import IMAGES_DIR, Frame, read_scene, with_frame_sizes, write_scene_json

    scene = read_scene(scene_dir)
    size = (scene.width, scene.height)
    tmp = out.with_name(out.name + ".tmp")
    shutil.rmtree(tmp, ignore_errors=True)
    (tmp / IMAGES_DIR).mkdir(parents=True)
    frames = []
    for f in scene.frames:
        img, cam, _ = resize_with_camera(read_image(scene_dir / IMAGES_DIR / f.name), f.camera, size)
        write_png(tmp / IMAGES_DIR / f.name, img)
        frames.append(Frame(f.name, cam, f.c2w))
    scene.frames = frames
    scene.extra = with_frame_sizes(scene.extra, [size] * len(frames), size)
    write_scene_json(scene, tmp)
    tmp.rename(out)


def prepare(work: Path, squeezed: bool = True) -> dict[str, Path]:
    """Ingested scenes (cached): colmap and mvimgnet layouts, and (if
    ``squeezed``) the squeezed copy."""
    from gs2e.io.ingest import ingest_scene

    src = DATA / "mouse_colmap"
    out = {}
    for layout in ("colmap", "mvimgnet"):
        d = work / f"ingest_{layout}"
        if not d.exists():
            ingest_scene(src, layout, d)
        out[layout] = d
    if not squeezed:
        return out
    sq = work / "ingest_squeezed"
    if not sq.exists():
        squeezed_copy(out["colmap"], sq)
    out["squeezed"] = sq
    return out


def same_views(a: Path, b: Path) -> bool:
    """Whether two ingested scenes hold the same images, sizes and cameras."""
    from gs2e.io.scene import IMAGES_DIR, read_scene

    sa, sb = read_scene(a), read_scene(b)
    if [f.name for f in sa.frames] != [f.name for f in sb.frames]:
        return False
    return all(fa.camera == fb.camera and sa.frame_size(i) == sb.frame_size(i)
               and (a / IMAGES_DIR / fa.name).read_bytes() == (b / IMAGES_DIR / fb.name).read_bytes()
               for i, (fa, fb) in enumerate(zip(sa.frames, sb.frames)))


def run_variant(name: str, scene_dir: Path, work: Path, target: tuple[int, int], seed: int) -> dict:
    """SfM (the capture's own cameras) + training + held-out renders of one variant."""
    from gs2e.io.scene import read_scene
    from gs2e.sfm.colmap_sfm import run_sfm
    from gs2e.sfm.settings import SfmSettings
    from gs2e.splat.evaluate import render_views
    from gs2e.splat.settings import SplatSettings
    from gs2e.splat.train import train

    sfm, model, views = work / f"sfm_{name}", work / f"splat_{name}", work / f"views_{name}"
    for d in (sfm, model, views):
        shutil.rmtree(d, ignore_errors=True)
    run_sfm(scene_dir, sfm, SfmSettings.defaults(reuse_poses=True), seed=seed, threads=2)
    with harness.clock() as t:
        stats = train(sfm, model, SplatSettings.defaults(), seed=seed, threads=2, target_size=target)
    rows = render_views(model, sfm, views, "test")
    src = read_scene(scene_dir)  # the views' orientation in the capture
    orient = {f.name: ("portrait" if src.frame_size(i)[1] > src.frame_size(i)[0] else "landscape")
              for i, f in enumerate(src.frames)}
    ingested = read_scene(work / "ingest_colmap")
    true_orient = {f.name: ("portrait" if ingested.frame_size(i)[1] > ingested.frame_size(i)[0]
                            else "landscape") for i, f in enumerate(ingested.frames)}
    for r in rows:
        r.update(variant=name, orientation=true_orient[r["view"]], stored_as=orient[r["view"]])
    return {"variant": name, "rows": rows, "test_psnr": stats["test_psnr"], "test_ssim": stats["test_ssim"],
            "iterations": stats["iterations"], "n_gaussians": stats["n_gaussians"],
            "train_size": f"{stats['train_width']}x{stats['train_height']}", "wall_s": t.wall_s, "cpu_s": t.cpu_s}


def plot(df: pd.DataFrame, title: str) -> Path:
    """Mean held-out PSNR per orientation and variant, as
    benchmarks/results/bench_mixed_views.png; returns the path."""
    plt = harness.pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 3.6))
    groups = ["landscape", "portrait", "all"]
    variants = list(dict.fromkeys(df["variant"]))
    w = 0.8 / len(variants)
    for k, v in enumerate(variants):
        d = df[df["variant"] == v]
        vals = [d[d["orientation"] == g]["psnr"].mean() if g != "all" else d["psnr"].mean() for g in groups]
        ax.bar(np.arange(3) + k * w, vals, w, label=v)
        for x, y in zip(np.arange(3) + k * w, vals):
            ax.text(x, y + 0.1, f"{y:.1f}", ha="center", fontsize=8)
    ax.set_xticks(np.arange(3) + w * (len(variants) - 1) / 2, [f"{g} held-out views" for g in groups])
    ax.set_ylabel("PSNR (dB)")
    lo = df["psnr"].min()
    ax.set_ylim(max(0, lo - 3), df["psnr"].max() + 1.5)
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    return harness.save_plot(fig, "bench_mixed_views")


def main() -> int:
    from gs2e.events.sensors import SENSORS

    ap = harness.parser(__doc__, quick="only the ingest check, mvimgnet against colmap (no SfM or "
                        "training, nothing written; under a minute)")
    ap.add_argument("--sensor", default="davis346", choices=list(SENSORS))
    ap.add_argument("--work", type=Path, default=RESULTS / "bench_mixed_views_work")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    if not (DATA / "mouse_colmap").is_dir():
        print(f"{DATA / 'mouse_colmap'} is absent", file=sys.stderr)
        return 2
    from gs2e.events.sensors import get_sensor

    target = tuple(get_sensor(event_settings({**load_section("events"), "sensor": a.sensor})).size)
    a.work.mkdir(parents=True, exist_ok=True)
    scenes = prepare(a.work, squeezed=not a.quick)
    mvimgnet_same = same_views(scenes["colmap"], scenes["mvimgnet"])
    if a.quick:
        harness.report(None, f"mouse_colmap: mvimgnet layout ingests the same views as colmap: "
                       f"{'yes' if mvimgnet_same else 'NO'} (quick: no SfM or training)")
        return 0
    runs = [run_variant(n, scenes[k], a.work, target, a.seed)
            for n, k in [("own size", "colmap"), ("squeezed", "squeezed")]]
    df = pd.DataFrame([r for run in runs for r in run["rows"]])
    df["sensor"] = a.sensor
    files = [harness.write_csv("bench_mixed_views", df)]
    print(f"mouse_colmap, {a.sensor} ({target[0]}x{target[1]}), seed {a.seed}; "
          f"mvimgnet layout ingests the same views as colmap: {'yes' if mvimgnet_same else 'NO'}")
    print(f"{'variant':10s} {'train at':>9s} {'steps':>6s} {'Gauss.':>7s} {'CPU s':>7s} "
          f"{'PSNR':>6s} {'SSIM':>6s} {'land.':>6s} {'portr.':>6s}")
    for r in runs:
        d = df[df["variant"] == r["variant"]]
        land = d[d["orientation"] == "landscape"]["psnr"].mean()
        port = d[d["orientation"] == "portrait"]["psnr"].mean()
        print(f"{r['variant']:10s} {r['train_size']:>9s} {r['iterations']:6d} {r['n_gaussians']:7d} "
              f"{r['cpu_s']:7.0f} {r['test_psnr']:6.2f} {r['test_ssim']:6.3f} {land:6.2f} {port:6.2f}")
    own, sq = runs
    title = (f"mouse_colmap held-out PSNR at {a.sensor}: own size {own['test_psnr']:.2f} dB, "
             f"squeezed {sq['test_psnr']:.2f} dB")
    files.append(plot(df, title))
    files.append(RESULTS / "bench_mixed_views.json")
    files[-1].write_text(json.dumps(
        {k: v for r in runs for k, v in [(r["variant"], {x: y for x, y in r.items() if x != "rows"})]},
        indent=1))
    harness.report(None, f"{title} ({own['test_psnr'] - sq['test_psnr']:+.2f} dB)", files)
    return 0


if __name__ == "__main__":
    sys.exit(main())
