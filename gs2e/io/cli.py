"""``gs2e ingest``: a source scene -> the internal scene layout."""

from __future__ import annotations

import argparse
import logging

from gs2e.cli import add_config_args

LAYOUT_HELP = """layouts:
  demo, internal  a gs2e scene folder (scene.json + images/ [+ points3d.npz])
  folder          plain images in SRC or SRC/images, sorted by name, no poses
                  (PINHOLE guess fx=fy=1.2*max(W,H), flagged intrinsics_guess)
  colmap          SRC/images + SRC/sparse/0 (or SRC/sparse), .bin or .txt
  mvimgnet        an MVImgNet clip: images/ + sparse/0, video-ordered
  dl3dv           a DL3DV scene: images_N/ + nerfstudio transforms.json
                  (+ colmap/ sparse model for points)
  nerf            transforms.json / transforms_train.json (NeRF, instant-ngp,
                  nerfstudio); SRC may be the json file
"""


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "ingest",
        help="read a scene (folder, COLMAP, MVImgNet, DL3DV, NeRF) into the internal layout",
        description="Read a source scene, check it, optionally subsample views and downscale, "
                    "and write the internal layout (scene.json + images/*.png [+ points3d.npz]) "
                    "atomically to OUT.",
        epilog=LAYOUT_HELP,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    from gs2e.io.views import LAYOUTS  # light (numpy only); heavy imports stay in run()

    p.add_argument("--layout", required=True, choices=LAYOUTS, help="source layout (see below)")
    p.add_argument("--src", required=True, metavar="PATH", help="source scene folder (or json for nerf)")
    p.add_argument("--out", required=True, metavar="DIR", help="output scene folder")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gs2e.config import load_section
    from gs2e.io.ingest import ingest_scene

    log = logging.getLogger("gs2e.ingest")
    cfg = load_section("ingest", text=args.config_json, path=args.config)
    log.info("ingest config: %s", cfg)
    scene = ingest_scene(args.src, args.layout, args.out, cfg)
    log.info("scene %s: %d views %dx%d, poses=%s", args.out, len(scene.frames), scene.width,
             scene.height, scene.has_poses)
    return 0
