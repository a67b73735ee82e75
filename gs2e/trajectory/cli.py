"""``gs2e trajectory``: virtual camera trajectories for one scene."""

from __future__ import annotations

import argparse
import logging


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    p = sub.add_parser(
        "trajectory",
        help="smooth, densify and time virtual camera trajectories of a posed scene",
        description="Base trajectory (smoothing + velocity-controlled B-spline) timed by each "
                    "speed preset, plus novel-view mini-trajectories. Writes OUT/<name>.npz, "
                    "OUT/trajectories.json and OUT/trajectories.png atomically.")
    p.add_argument("--scene", required=True, metavar="DIR", help="scene folder (internal layout, with poses)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (replaced atomically)")
    p.add_argument("--seed", type=int, default=None,
                   help="seed of the mini-trajectory draws (default: trajectory.seed)")
    p.add_argument("--no-plot", action="store_true", help="skip trajectories.png")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from gs2e.common.log import timed
    from gs2e.io.scene import read_scene
    from gs2e.trajectory.io import write_outputs
    from gs2e.trajectory.settings import TrajectorySettings
    from gs2e.trajectory.stage import generate

    log = logging.getLogger("gs2e.trajectory")
    cfg = TrajectorySettings.load(args.config_json, args.config)
    seed = int(cfg.seed if args.seed is None else args.seed)
    timings: dict[str, float] = {}
    with timed("read scene", log, timings):
        scene = read_scene(args.scene)
    with timed("trajectories", log, timings):
        result = generate(scene, cfg, seed, timings)
    with timed("write outputs", log, timings):
        write_outputs(args.out, result, cfg, args.scene, plot=cfg.plot and not args.no_plot)
    for name, tr in result.trajectories.items():
        log.info("%s: %d poses, %.3f s, method %s", name, len(tr.t_us), tr.duration_us * 1e-6,
                 tr.meta["method"])
    return 0
