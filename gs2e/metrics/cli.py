"""``gs2e metrics`` (one scene's table) and ``gs2e summary`` (the dataset's)."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("metrics", help="join a scene's stage metrics into one parquet table",
                       description="One row per (scene, trajectory) with the sfm, train, trajectory, "
                                   "render and events metrics of results/<scene>, code version, "
                                   "config hash and seeds.")
    p.add_argument("--scene-dir", required=True, help="results/<scene>")
    p.add_argument("--scene-id", required=True)
    p.add_argument("--trajectories", nargs="*", default=[], help="trajectory names")
    p.add_argument("--config-json", default="{}", help="the scene's full config (for the hash)")
    p.add_argument("--seeds-json", default="{}", help="seeds per stage")
    p.add_argument("--out", required=True, help="parquet file (written atomically)")
    p.set_defaults(func=run_metrics)

    s = sub.add_parser("summary", help="concatenate scene metrics tables into the dataset summary")
    s.add_argument("tables", nargs="*", help="scene metrics.parquet files")
    s.add_argument("--status", default=None, help="scene_status.parquet of `gs2e dataset`: each scene's "
                   "status joins its rows, and a failed scene without a table becomes one row")
    s.add_argument("--out", required=True, help="parquet file (written atomically)")
    s.set_defaults(func=run_summary)


def run_metrics(args: argparse.Namespace) -> int:
    import json

    from gs2e.common.atomic import atomic_path
    from gs2e.metrics.collect import scene_table

    df = scene_table(args.scene_dir, args.scene_id, args.trajectories, json.loads(args.config_json),
                     json.loads(args.seeds_json))
    with atomic_path(args.out) as tmp:
        df.to_parquet(tmp, index=False)
    return 0


def run_summary(args: argparse.Namespace) -> int:
    import logging

    from gs2e.common.atomic import atomic_path
    from gs2e.metrics.collect import summary

    df = summary(args.tables, args.status)
    with atomic_path(args.out) as tmp:
        df.to_parquet(tmp, index=False)
    logging.getLogger("gs2e.metrics").info("summary: %d rows from %d scene tables", len(df), len(args.tables))
    return 0
