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
    p.add_argument("--run", default=None,
                   help="the run's name, <trajectory>[@<condition>] (default: the trajectory file's "
                        "stem); a lighting condition is recorded in the light column")
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

    r = sub.add_parser(
        "bench-real", help="the video task's methods on real recordings with APS frames",
        description="Reconstruct every APS frame after the first of each recording (an ECD sequence "
                    "folder or an .aedat4 file with frames) by direct integration and the "
                    "complementary filter from the first frame, by the learned networks of "
                    "bench.video_learned from events alone, and the first frame held; score against "
                    "the APS frames (see gs2e.bench.real_video); one row per recording x method x frame.")
    r.add_argument("recordings", nargs="+", help="ECD sequence folders or .aedat4 files with frames")
    r.add_argument("--out", required=True, help="output .parquet (written atomically)")
    add_config_args(r)
    r.set_defaults(func=run_real)

    m = sub.add_parser(
        "bench-sim2real", help="simulated against real events on the same scene under the same motion",
        description="Render the scene's model along a real recording's ground-truth camera path (an "
                    "ECD sequence folder), simulate events with each of bench.sim2real_variants (and "
                    "the event models of bench.sim2real_fit, fitted to the recording) and compare them "
                    "with the real events: count ratio, ON fraction, per-pixel count maps, rate over "
                    "time, inter-event intervals, edge alignment (see gs2e.bench.sim2real). Writes "
                    "OUT/distances.parquet, OUT/fit.json, OUT/trajectory.npz and OUT/sim2real.png.")
    m.add_argument("--model", required=True, help="the scene's trained model (gs2e train output)")
    m.add_argument("--scene", required=True, help="the scene the model was trained on (gs2e sfm output)")
    m.add_argument("--recording", required=True, help="the ECD sequence folder of the same scene")
    m.add_argument("--out", required=True, help="output folder (written atomically)")
    m.add_argument("--seed", type=int, default=0, help="the event models' seed")
    m.add_argument("--events-json", default=None, metavar="JSON",
                   help="the scene's events section as JSON (variant 'scene'; default: the defaults)")
    add_config_args(m)
    m.set_defaults(func=run_sim2real)

    _register_finetune(sub)


def _register_finetune(sub: argparse._SubParsersAction) -> None:
    # (defaults from FinetuneSettings when run, not imported here: every bench
    # rule's code version follows what register() imports)
    f = sub.add_parser(
        "bench-finetune", help="fine-tune PIE-Net-Lite on some scenes' events, score it on others and on "
                               "real recordings, before and after",
        description="Train the shipped PIE-Net-Lite (or PIE-Net) further on the frame windows of the "
                    "--train scenes of a results folder (gs2e.data), then score the shipped and the "
                    "fine-tuned weights on the --eval scenes and on real recordings with APS frames "
                    "(--real), as the video task scores learned methods (see gs2e.bench.finetune). "
                    "Writes DIR/weights.pt, DIR/scores.parquet (per frame), DIR/history.parquet "
                    "(loss and CPU seconds per step) and DIR/run.json.")
    f.add_argument("--root", required=True, help="results folder (holding <scene>/windows, events, frames)")
    f.add_argument("--train", required=True, help="comma-separated scene ids to train on")
    f.add_argument("--eval", default="", help="comma-separated scene ids to score on (held out)")
    f.add_argument("--real", action="append", default=[], metavar="PATH",
                   help="a real recording with APS frames to score on: an ECD sequence folder or an "
                        ".aedat4 file (repeatable)")
    f.add_argument("--out", required=True, help="output folder (written atomically)")
    for key, kind, help_ in (("variant", str, "network: pienet_lite or pienet (default pienet_lite)"),
                             ("steps", int, "optimiser steps (default 200)"),
                             ("batch", int, "sequences per step (default 4)"),
                             ("seq_frames", int, "frame intervals per sequence (default 8)"),
                             ("crop_px", int, "crop side, px (default 128)"),
                             ("lr", float, "Adam's learning rate (default 3e-4)"),
                             ("seed", int, "seed of crops, flips and picks (default 0)"),
                             ("loss", str, "robust = L1 after EVREAL's normalisation, as scored; l1; "
                                           "or both (default robust)")):
        f.add_argument("--" + key.replace("_", "-"), dest=key, type=kind, default=None, help=help_)
    f.set_defaults(func=run_finetune)


def run_bench(args: argparse.Namespace) -> int:
    from gs2e.bench.run import resolve, run_task
    from gs2e.common.threads import set_threads
    from gs2e.config import load_section

    set_threads(args.threads)
    cfg = load_section("bench", args.config_json, args.config)
    cfg["methods"] = list(dict.fromkeys(list(cfg["methods"]) + list(args.method)))
    run_task(args.task, args.frames, args.events, args.windows, args.trajectory, resolve(cfg, args.seed),
             args.out, args.png, scene_id=args.scene_id, trajectory=args.run)
    return 0


def run_real(args: argparse.Namespace) -> int:
    from gs2e.bench.real_video import run_recordings
    from gs2e.config import load_section

    cfg = load_section("bench", args.config_json, args.config)
    run_recordings(args.recordings, float(cfg["real_video_theta"]), float(cfg["video_cf_alpha_rad_s"]),
                   tuple(cfg["video_learned"]), args.out)
    return 0


def run_sim2real(args: argparse.Namespace) -> int:
    from gs2e.bench.sim2real import run_sim2real as run, settings_from_config
    from gs2e.config import load_section

    bench = load_section("bench", args.config_json, args.config)
    events = load_section("events", args.events_json)
    run(args.model, args.scene, args.recording, args.out, events,
        settings_from_config(bench, args.seed))
    return 0


def run_summary(args: argparse.Namespace) -> int:
    from gs2e.bench.summary import write_summary

    write_summary(args.tables, args.out)
    return 0


def run_finetune(args: argparse.Namespace) -> int:
    from gs2e.bench.finetune import FinetuneSettings, run_finetune_cli

    keys = ("variant", "steps", "batch", "seq_frames", "crop_px", "lr", "seed", "loss")
    settings = FinetuneSettings(**{k: getattr(args, k) for k in keys if getattr(args, k) is not None})
    names = lambda text: [n for n in text.split(",") if n.strip()]  # noqa: E731
    run_finetune_cli(args.root, names(args.train), names(args.eval), args.real, args.out, settings)
    return 0
