"""``gs2e demo-scene``: synthesise the built-in demo scene."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    from gs2e.cli import add_config_args

    p = subparsers.add_parser(
        "demo-scene",
        help="render the built-in demo scene (photos from scikit-image, known cameras)",
        description="Ray-cast a small static scene textured with photographs bundled in "
                    "scikit-image from views on an orbit, and write it in the gs2e scene "
                    "layout: images/*.png, scene.json (PINHOLE intrinsics, ground-truth "
                    "camera-to-world poses, OpenCV axes) and points3d.npz (surface points "
                    "with their colours). The output folder is replaced atomically.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    p.add_argument("--out", required=True, metavar="DIR", help="output scene folder")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gs2e.demo.io import generate_demo_scene
    from gs2e.demo.settings import DemoSettings

    cfg = DemoSettings.load(args.config_json, args.config)
    generate_demo_scene(args.out, cfg)
    return 0
