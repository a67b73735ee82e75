"""``gs2e render``: dataset frames along a trajectory."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args, size_arg

    p = sub.add_parser(
        "render", help="sharp and motion-blurred frames, depth and alpha along a trajectory",
        description="Render a trained model (gs2e train output) along a trajectory file (gs2e "
                    "trajectory output) at render.fps: rgb/, blur/, depth/, alpha/, frames.parquet, "
                    "transforms.json.")
    p.add_argument("--model", required=True, help="gs2e train output folder")
    p.add_argument("--trajectory", required=True, help="trajectory .npz")
    p.add_argument("--out", required=True, help="output folder (written atomically)")
    p.add_argument("--scene-id", default=None)
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads (default or -1: the CPUs this process may use)")
    p.add_argument("--sensor-size", type=size_arg, metavar="WxH",
                   help="render through the event sensor's camera: this pixel array, fitted to "
                        "the trajectory's camera (the workflow passes events.sensor's; "
                        "render.scale does not apply)")
    p.add_argument("--sensor-fit", default="cover", choices=["cover", "contain"],
                   help="how the sensor's view is fitted (events.sensor_fit; default cover)")
    p.add_argument("--light-json", default=None, metavar="JSON",
                   help="the run's lighting condition (gs2e.light; the workflow passes a run "
                        "<trajectory>@<condition>'s)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the frame camera's noise (render.camera.model sensor)")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gs2e.common.threads import set_threads
    from gs2e.render.dataset import render_dataset
    from gs2e.render.settings import RenderSettings

    from gs2e.light.settings import Condition

    cfg = RenderSettings.load(args.config_json, args.config)
    light = Condition.from_json(args.light_json) if args.light_json else None
    set_threads(args.threads)
    render_dataset(args.model, args.trajectory, args.out, cfg, scene_id=args.scene_id,
                   sensor=(args.sensor_size, args.sensor_fit) if args.sensor_size else None,
                   light=light, seed=args.seed)
    return 0
