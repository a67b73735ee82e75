"""``gs2e sfm``: recover cameras of an ingested scene with COLMAP."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    p = sub.add_parser(
        "sfm", help="structure-from-motion with COLMAP (pycolmap)",
        description="SIFT extraction, matching, incremental mapping (or triangulation with "
                    "known poses), undistortion to PINHOLE. Writes an internal-layout scene "
                    "plus sparse/0 (COLMAP binary), sfm_stats.json and metrics.parquet.")
    p.add_argument("--scene", required=True, help="ingested scene folder (gs2e ingest output)")
    p.add_argument("--out", required=True, help="output folder (written atomically)")
    p.add_argument("--seed", type=int, default=0, help="COLMAP mapper seed")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads (default: sfm.num_threads; -1: the CPUs this process may use)")
    p.add_argument("--scene-id", default=None, help="scene id recorded in the metrics")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gs2e.sfm.colmap_sfm import run_sfm
    from gs2e.sfm.settings import SfmSettings

    cfg = SfmSettings.load(args.config_json, args.config)
    run_sfm(args.scene, args.out, cfg, seed=args.seed, threads=args.threads,
            scene_id=args.scene_id)
    return 0
