"""``gs2e windows``: aligned event windows of a trajectory;
``gs2e export``: a trajectory in the layout an event-based 3D method reads."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    w = sub.add_parser(
        "windows", help="index ranges of the events of every frame (between frames, over exposures)",
        description="Write windows/<trajectory>.parquet: for every frame of a rendered trajectory "
                    "the index range [i0, i1) of its events in events.h5 between consecutive frames "
                    "and over the blurred frame's exposure, with coverage flags (see gs2e.export.windows).")
    w.add_argument("--frames", required=True, help="frames folder of gs2e render (frames.parquet)")
    w.add_argument("--events", required=True, help="events folder of gs2e events (events.h5, stats.json)")
    w.add_argument("--out", required=True, help="output .parquet (written atomically)")
    w.set_defaults(func=run_windows)

    e = sub.add_parser(
        "export", help="write a trajectory in the layout of EventNeRF, E2NeRF/E2GS, EvDeblurNeRF, "
                       "IncEventGS or Event-3DGS, or as flow / IMU ground truth and ROS bags",
        description="Export one trajectory of a scene's results folder (frames/, events/, windows/, "
                    "trajectories/, sfm/) in the exact layout a method's own data loader reads, or "
                    "its ground truth (optical flow, IMU) and ROS bags; gs2e_export.json records "
                    "units, polarity, time origin and any normalisation.")
    e.add_argument("--scene-dir", required=True, help="results/<scene> folder")
    e.add_argument("--trajectory", required=True, help="trajectory name (e.g. base_medium)")
    e.add_argument("--format", required=True, dest="fmt",
                   help="a format registered in gs2e.export.formats (config/README.md, export.formats, "
                        "lists the built-in ones); an unknown name is an error listing them")
    e.add_argument("--out", required=True, help="output folder (replaced atomically)")
    e.add_argument("--windows", help="windows table (default <scene-dir>/windows/<trajectory>.parquet)")
    e.add_argument("--scene-id", default=None)
    e.add_argument("--seed", type=int, default=0,
                   help="seed of the formats that draw random numbers (IMU noise); the workflow "
                        "derives it from the config's seed, the scene and the stage")
    add_config_args(e)
    e.set_defaults(func=run_export)


def run_windows(args: argparse.Namespace) -> int:
    from gs2e.export.windows import write_windows

    write_windows(args.frames, args.events, args.out)
    return 0


def run_export(args: argparse.Namespace) -> int:
    from gs2e.export.run import export_trajectory
    from gs2e.export.settings import ExportSettings

    cfg = ExportSettings.load(args.config_json, args.config)
    export_trajectory(args.scene_dir, args.trajectory, args.fmt, args.out, cfg,
                      windows_file=args.windows, scene_id=args.scene_id, seed=args.seed)
    return 0
