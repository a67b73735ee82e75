"""``gs2e bench``: a downstream task on one trajectory of a dataset;
``gs2e bench-summary``: the dataset's bench table."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.bench.tasks import task_names
    from gs2e.cli import add_config_args

    p = sub.add_parser(
        "bench", help="benchmark deblurring or video reconstruction on a trajectory's own ground truth",
        description="Evaluate event-based deblurring (--task deblur: the blurred frame, EDI with the "
                    "simulator's threshold and with one chosen per frame) or video reconstruction "
                    "(--task video: direct integration and a complementary filter after one keyframe, "
                    "and the learned PIE-Net / PIE-Net-Lite, bench.video_learned) "
                    "or event-based 3D reconstruction (--task recon3d: 3DGS trained from the "
                    "trajectory's events, events + blurred frames, or sharp frames, scored at held-out "
                    "poses; see gs2e.bench.recon3d) "
                    "against the sharp frames, plus any --method package.module:function; writes one "
                    "row per method x frame (see gs2e.bench.run) and a strip of example crops.")
    p.add_argument("--task", required=True, choices=task_names())
    p.add_argument("--frames", required=True, help="frames folder of gs2e render")
    p.add_argument("--events", required=True, help="events folder of gs2e events")
    p.add_argument("--windows", required=True, help="windows table of gs2e windows")
    p.add_argument("--trajectory", default=None,
                   help="the trajectory .npz (its speed preset is recorded)")
    p.add_argument("--out", required=True, help="output .parquet (written atomically)")
    p.add_argument("--png", required=True, help="example crops .png (written atomically)")
    p.add_argument("--method", action="append", default=[], metavar="MODULE:FUNCTION",
                   help="also evaluate this callable (repeatable; see gs2e.bench.methods)")
    p.add_argument("--scene-id", default=None)
    p.add_argument("--seed", type=int, default=0, help="seed of recon3d's initialisation and sampling "
                                                       "(the workflow derives it per scene x trajectory)")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads (default or -1: the CPUs this process may use)")
    add_config_args(p)
    p.set_defaults(func=run_bench)

    s = sub.add_parser("bench-summary", help="collect bench tables into one (per scene x trajectory "
                                             "x task x method)",
                       description="Aggregate bench/<task>/<trajectory>.parquet tables: pooled PSNR, "
                                   "mean SSIM, motion over the exposure, video PSNR at 0.5 s and "
                                   "at the end, drift (see gs2e.bench.summary).")
    s.add_argument("tables", nargs="*", help="bench tables")
    s.add_argument("--out", required=True, help="output .parquet")
    s.set_defaults(func=run_summary)


def run_bench(args: argparse.Namespace) -> int:
    from gs2e.bench.run import resolve, run_task
    from gs2e.common.threads import set_threads
    from gs2e.config import load_section

    set_threads(args.threads)
    cfg = load_section("bench", args.config_json, args.config)
    cfg["methods"] = list(dict.fromkeys(list(cfg["methods"]) + list(args.method)))
    run_task(args.task, args.frames, args.events, args.windows, args.trajectory, resolve(cfg, args.seed),
             args.out, args.png, scene_id=args.scene_id)
    return 0


def run_summary(args: argparse.Namespace) -> int:
    from gs2e.bench.summary import write_summary

    write_summary(args.tables, args.out)
    return 0
