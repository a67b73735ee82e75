"""``gs2e train`` and ``gs2e render-views``."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args, size_arg

    p = sub.add_parser(
        "train", help="3D Gaussian Splatting on the CPU (or import an official model)",
        description="Train a Gaussian model of an sfm output scene, or import one (splat.model_source=ply). "
                    "Writes point_cloud/iteration_N/point_cloud.ply (official layout), cameras.json, "
                    "model.json, train_stats.json, metrics.parquet and curve.parquet.")
    p.add_argument("--scene", required=True, help="sfm output folder (PINHOLE views + points3d.npz)")
    p.add_argument("--out", required=True, help="output folder (written atomically)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default or -1: the CPUs this process may use)")
    p.add_argument("--scene-id", default=None, help="scene id recorded in the metrics")
    p.add_argument("--checkpoint-dir", default=None,
                   help="where checkpoints go (default: <out>.ckpt); a matching one is resumed")
    p.add_argument("--no-resume", action="store_true", help="ignore existing checkpoints")
    p.add_argument("--target-size", type=size_arg, metavar="WxH",
                   help="the largest image the outputs need (the workflow passes the event "
                        "sensor's array): with splat.max_side=auto the views train at the "
                        "smallest size that still covers it")
    add_config_args(p)
    p.set_defaults(func=run_train)

    r = sub.add_parser("render-views", help="render a trained model at the scene's cameras",
                       description="Render a gs2e train output at the cameras of a scene and "
                                   "write PNGs (and PSNR/SSIM against the scene's images).")
    r.add_argument("--model", required=True, help="gs2e train output folder")
    r.add_argument("--scene", required=True, help="scene folder whose cameras to render")
    r.add_argument("--out", required=True, help="output folder for renders (atomic)")
    r.add_argument("--views", choices=["test", "train", "all"], default="test")
    r.add_argument("--test-every", type=int, default=None,
                   help="hold-out split (default: the one the model was trained with)")
    r.add_argument("--backend", choices=["cpu", "gsplat", "auto"], default="cpu",
                   help="rasterizer: cpu (default), gsplat (CUDA, optional) or auto")
    r.set_defaults(func=run_render_views)


def run_train(args: argparse.Namespace) -> int:
    from gs2e.splat.settings import SplatSettings
    from gs2e.splat.train import train

    cfg = SplatSettings.load(args.config_json, args.config)
    train(args.scene, args.out, cfg, seed=args.seed, threads=args.threads, scene_id=args.scene_id,
          checkpoint_dir=args.checkpoint_dir, resume=not args.no_resume, target_size=args.target_size)
    return 0


def run_render_views(args: argparse.Namespace) -> int:
    from gs2e.splat.evaluate import render_views

    render_views(args.model, args.scene, args.out, args.views, args.test_every, args.backend)
    return 0
