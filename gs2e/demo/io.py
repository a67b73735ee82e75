"""Write the demo scene in the internal scene layout (images/, scene.json, points3d.npz)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np

from gs2e.common import atomic_dir, progress, timed
from gs2e.common.settings import require
from gs2e.demo.settings import DemoSettings
from gs2e.demo.world import (TARGET, WOBBLE_PERIODS, build_world, check_orbit, intrinsics,
                             orbit_c2w, render_view, sample_points, wall_size)
from gs2e.io.images import write_png
from gs2e.io.scene import IMAGES_DIR, Camera, Frame, Scene, write_scene_json

log = logging.getLogger("gs2e.demo")


def generate_demo_scene(out: str | Path, cfg: DemoSettings) -> dict:
    """Render the demo scene described by ``cfg`` into folder ``out``
    (replaced atomically). Returns timings (s) and counts."""
    check_orbit(require(cfg, DemoSettings, "generate_demo_scene"))
    out = Path(out)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    W, H, ss = int(cfg.width), int(cfg.height), int(cfg.supersample)
    wall_r, wall_h = wall_size(cfg.orbit_radius)
    with timed("build world (textures from scikit-image)", log, timings):
        world = build_world(cfg.seed, wall_r, wall_h)
    fx, fy, cx, cy = intrinsics(W, H, cfg.fov_deg)
    cam = Camera(fx, fy, cx, cy, "PINHOLE", [])
    c2ws = orbit_c2w(cfg.n_views, cfg.orbit_radius, cfg.orbit_elevation_deg,
                     cfg.elevation_wobble_deg)
    frames = []
    with atomic_dir(out) as tmp:
        (tmp / IMAGES_DIR).mkdir()
        with timed(f"render {len(c2ws)} views at {W}x{H} (supersample {ss})", log, timings):
            for k, c2w in enumerate(progress(c2ws, desc="demo views")):
                img = render_view(world, c2w, fx, fy, cx, cy, W, H, ss)
                name = f"{k:03d}.png"
                write_png(tmp / IMAGES_DIR / name, img)
                frames.append(Frame(name, cam, c2w))
        with timed("sample surface points", log, timings):
            rng = np.random.default_rng(np.random.SeedSequence([int(cfg.seed), 11]))
            xyz, rgb = sample_points(world, int(cfg.n_points), rng)
        scene = Scene(width=W, height=H, frames=frames, layout="demo",
                      source="gs2e demo-scene (scikit-image photographs)",
                      points_xyz=xyz, points_rgb=rgb,
                      extra={"generator": "gs2e.demo", "config": dict(sorted(cfg.as_dict().items())),
                             "world_up": [0.0, 0.0, 1.0], "units": "scene units",
                             "target": TARGET.tolist(), "wobble_periods": WOBBLE_PERIODS,
                             "wall_radius": wall_r, "wall_height": wall_h,
                             "textures": world.atlas.names,
                             "points": "surface samples with their rendered (static) colours"})
        write_scene_json(scene, tmp)
    total = time.perf_counter() - t0
    render_s = next(v for k, v in timings.items() if k.startswith("render"))
    log.info("demo scene: %d views %dx%d, %d points -> %s in %.2f s (%.3f s/view)",
             len(frames), W, H, len(xyz), out, total, render_s / len(frames))
    return {"n_views": len(frames), "n_points": int(len(xyz)), "seconds": total, "timings": timings}
