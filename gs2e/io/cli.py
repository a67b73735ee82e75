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
  ecd             an Event Camera Dataset sequence: images.txt, groundtruth.txt
                  (poses interpolated at the frames' times), calib.txt
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
    _register_scenes(subparsers)


def _register_scenes(subparsers) -> None:
    from gs2e.io.selection import DATASETS

    p = subparsers.add_parser(
        "scenes",
        help="write a scenes table from MVImgNet / DL3DV scene id lists (the paper's selection)",
        description="Map user-supplied scene ids to folders by the datasets' release layouts "
                    "(MVImgNet <root>/<category>/<clip>, DL3DV <root>/<hash>), check that each "
                    "exists (unless --no-check), and write a scenes table atomically. Id lists: "
                    "one id per line, '#' comments; MVImgNet ids are 'category/clip' (or a bare "
                    "clip, found under <root>/*/), DL3DV ids a hash or a path below the root "
                    "such as '1K/<hash>'. Scene ids become mvi_<category>_<clip> and dl3dv_<hash>.",
    )
    for ds, (_, _, over) in DATASETS.items():
        name = {"mvimgnet": "MVImgNet", "dl3dv": "DL3DV"}[ds]
        p.add_argument(f"--{ds}-root", metavar="DIR", help=f"{name} dataset root")
        p.add_argument(f"--{ds}-ids", metavar="TXT", help=f"{name} id list (needs --{ds}-root)")
        p.add_argument(f"--overrides-{ds}", metavar="OVERRIDES", default=over,
                       help=f"overrides column for every {name} scene (default: the paper's "
                            f"'{over}'; '' for none)")
    p.add_argument("--no-check", action="store_true",
                   help="do not check that the folders exist (write or review the table on a machine "
                        "without the data; `snakemake -n` still needs the folders, empty ones will do)")
    p.add_argument("--out", required=True, metavar="TSV", help="scenes table to write")
    p.set_defaults(func=run_scenes)


def run_scenes(args: argparse.Namespace) -> int:
    from gs2e.common.errors import ConfigError
    from gs2e.io.selection import DATASETS, build_rows, read_id_list, write_scenes_table

    log = logging.getLogger("gs2e.scenes")
    selections, summary = [], []
    for ds in DATASETS:
        root, ids = getattr(args, f"{ds}_root"), getattr(args, f"{ds}_ids")
        if bool(root) != bool(ids):
            raise ConfigError(f"--{ds}-root and --{ds}-ids go together")
        if ids:
            lst = read_id_list(ids, ds)
            selections.append((lst, root, getattr(args, f"overrides_{ds}")))
            summary.append(f"{len(lst)} {ds}")
    if not selections:
        raise ConfigError("no id list given (--mvimgnet-ids and/or --dl3dv-ids)")
    rows = build_rows(selections, check=not args.no_check)
    comment = ("written by `gs2e scenes` from " + ", ".join(
        f"{getattr(args, f'{ds}_ids')} ({getattr(args, f'{ds}_root')})"
        for ds in DATASETS if getattr(args, f"{ds}_ids"))
        + ("\nfolders NOT checked (--no-check)" if args.no_check else ""))
    write_scenes_table(rows, args.out, comment)
    log.info("wrote %s: %d scenes (%s)%s", args.out, len(rows), ", ".join(summary),
             "; folders not checked" if args.no_check else "")
    return 0


def run(args: argparse.Namespace) -> int:
    from gs2e.io.ingest import ingest_scene
    from gs2e.io.settings import IngestSettings

    log = logging.getLogger("gs2e.ingest")
    cfg = IngestSettings.load(args.config_json, args.config)
    log.info("ingest config: %s", cfg.as_dict())
    scene = ingest_scene(args.src, args.layout, args.out, cfg)
    log.info("scene %s: %d views %dx%d, poses=%s", args.out, len(scene.frames), scene.width,
             scene.height, scene.has_poses)
    return 0
