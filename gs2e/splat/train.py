"""3D Gaussian Splatting training on the CPU.

Follows the official recipe (Adam with per-parameter learning rates, position
lr decaying log-linearly, 0.8 L1 + 0.2 (1 - SSIM), clone/split/prune, opacity
reset, SH degree schedule, every ``test_every``-th view held out) and adds what
makes it cheap on a CPU: a coarse-to-fine resolution schedule, a Gaussian
budget measured from image detail, an SH degree chosen from the view
dependence the SfM tracks show, and early stopping when held-out PSNR
plateaus. Checkpoints allow resuming an interrupted run.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gs2e.common.atomic import atomic_dir, atomic_path, sweep_output, write_json_atomic
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger, timed
from gs2e.common.progress import progress
from gs2e.io.scene import IMAGES_DIR, Scene, read_scene
from gs2e.splat.backend import resolve_backend
from gs2e.splat.init import init_from_points
from gs2e.splat.loss import photometric_loss, psnr, ssim
from gs2e.splat.model import from_params, render, save_model, to_params
from gs2e.splat.ply import read_ply, write_cameras_json
from gs2e.splat.rasterize import NonFiniteError, SplatCamera, rasterize
from gs2e.splat.scene_stats import choose_sh_degree, detail_budget, view_dependence
from gs2e.splat.strategy import PARAMS, Adam, DensifyConfig, GradStats, densify_and_prune, reset_opacity

log = get_logger("gs2e.splat")


def set_threads(threads: int | None) -> None:
    """CPU threads for torch and the numba kernels (None or <= 0: leave as is)."""
    if threads and threads > 0:
        import numba

        torch.set_num_threads(threads)
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


# ----------------------------------------------------------------- data
@dataclass
class View:
    name: str
    c2w: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    images: dict[int, torch.Tensor]  # downscale factor -> (H, W, 3) float32 in [0,1]

    def camera(self, downscale: int) -> tuple[SplatCamera, torch.Tensor]:
        img = self.images[downscale]
        h, w = img.shape[:2]
        full = self.images[1]
        sx, sy = w / full.shape[1], h / full.shape[0]
        cam = SplatCamera.from_c2w(self.c2w, self.fx * sx, self.fy * sy, self.cx * sx,
                                   self.cy * sy, w, h)
        return cam, img


def load_views(scene_dir: Path, scene: Scene, downscales: list[int]) -> list[View]:
    import cv2

    from gs2e.io.images import read_image

    views = []
    for f in progress(scene.frames, desc="loading views"):
        if f.c2w is None:
            raise InputError(f"{scene_dir}: frame {f.name} has no pose; run sfm first")
        if f.camera.model not in ("PINHOLE", "SIMPLE_PINHOLE"):
            raise InputError(f"{scene_dir}: frame {f.name} has a {f.camera.model} camera; "
                             "training needs undistorted PINHOLE views (gs2e sfm output)")
        rgb = read_image(scene_dir / IMAGES_DIR / f.name)
        imgs = {}
        for d in sorted(set(downscales)):
            im = rgb if d == 1 else cv2.resize(
                rgb, (max(1, rgb.shape[1] // d), max(1, rgb.shape[0] // d)), interpolation=cv2.INTER_AREA)
            imgs[d] = torch.from_numpy(im.astype(np.float32) / 255.0)
        views.append(View(f.name, f.c2w, f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy, imgs))
    return views


def split_views(views: list[View], test_every: int) -> tuple[list[View], list[View]]:
    """Every ``test_every``-th view (in natural name order, as everywhere in
    gs2e, starting with the first) is held out, as the official code's LLFF
    hold-out; 0 disables the split. Both lists are in natural name order."""
    from gs2e.io.views import natural_key

    order = sorted(range(len(views)), key=lambda i: natural_key(views[i].name))
    if test_every <= 0 or len(views) < 3:
        return views, []
    test = {order[i] for i in range(0, len(order), test_every)}
    return [views[i] for i in order if i not in test], [views[i] for i in order if i in test]


def scene_extent(views: list[View]) -> float:
    """1.1 x the largest camera distance from the cameras' centroid (3DGS)."""
    c = np.stack([v.c2w[:3, 3] for v in views])
    r = float(np.max(np.linalg.norm(c - c.mean(0), axis=1)))
    return 1.1 * r if r > 0 else 1.0


# ----------------------------------------------------------------- evaluation
def evaluate(p, views: list[View], background, sh_degree: int, backend: str = "cpu") -> dict[str, float]:
    """Mean PSNR (dB) and SSIM over ``views`` at full resolution."""
    if not views:
        return {"psnr": float("nan"), "ssim": float("nan")}
    ps, ss = [], []
    with torch.no_grad():
        for v in views:
            cam, gt = v.camera(1)
            img = render(p, cam, background, sh_degree, backend)[0].clamp(0, 1)
            ps.append(psnr(img, gt))
            ss.append(float(ssim(img, gt)))
    return {"psnr": float(np.mean(ps)), "ssim": float(np.mean(ss))}


def downscale_at(schedule: list[list[int]], it: int) -> int:
    """Downscale factor of the coarse-to-fine schedule [[from_iteration, factor], ...]."""
    d = 1
    for start, factor in sorted(schedule):
        if it >= start:
            d = int(factor)
    return d


def position_lr(it: int, cfg: dict, extent: float) -> float:
    """Log-linear decay from lr_position_init to lr_position_final over max_iterations."""
    t = min(1.0, it / max(1, cfg["max_iterations"]))
    lo, hi = cfg["lr_position_final"], cfg["lr_position_init"]
    return extent * math.exp((1 - t) * math.log(hi) + t * math.log(lo))


def config_hash(cfg: dict, scene_dir: Path) -> str:
    return hashlib.sha256(json.dumps([cfg, str(scene_dir)], sort_keys=True).encode()).hexdigest()[:16]


# ----------------------------------------------------------------- training
def train(scene_dir: str | Path, out_dir: str | Path, cfg: dict, seed: int = 0,
          threads: int | None = None, scene_id: str | None = None,
          checkpoint_dir: str | Path | None = None, resume: bool = True,
          interrupt_after: int | None = None) -> dict[str, Any]:
    """Train (or, with ``model_source: ply``, import) a Gaussian model of the
    scene in ``scene_dir`` (an sfm output: PINHOLE views with poses and
    points3d.npz; its ``sparse/0`` tracks are used to choose the SH degree).

    Writes atomically to ``out_dir``: ``point_cloud/iteration_N/point_cloud.ply``
    (official layout), ``cameras.json``, ``model.json`` (what downstream stages
    read), ``train_stats.json``, ``metrics.parquet`` (one row) and
    ``curve.parquet`` (held-out PSNR/SSIM against wall time and iteration).
    Checkpoints go to ``checkpoint_dir`` (default ``<out_dir>.ckpt``) and are
    resumed when their config and seed match; they are removed after success.
    A resumed run continues exactly where the interrupted one stopped (view
    order, densification statistics, random states), so it writes the same
    model bytes as an uninterrupted run.

    ``interrupt_after``: stop after that many steps in total, leaving a
    checkpoint and writing no output (time-sliced jobs; tests of resume).
    Returns the statistics (``{"interrupted": True, "iteration": N}`` then).

    Raises InputError (naming the file) for unusable scenes and
    NonFiniteError (naming the iteration and view) when parameters or
    gradients become NaN/inf; no output is written then.
    """
    scene_dir, out_dir = Path(scene_dir), Path(out_dir)
    backend = resolve_backend(cfg["backend"])
    set_threads(threads)
    scene = read_scene(scene_dir)
    t0 = time.perf_counter()
    schedule = cfg["resolution_schedule"]
    views = load_views(scene_dir, scene, [1] + [int(f) for _, f in schedule])
    train_v, test_v = split_views(views, cfg["test_every"])
    extent = scene_extent(train_v)
    bg = torch.tensor(cfg["background"], dtype=torch.float32)
    timings: dict[str, float] = {}
    stats: dict[str, Any] = {"backend": backend, "n_views": len(views), "n_train_views": len(train_v),
                             "n_test_views": len(test_v), "extent": extent,
                             "test_every": cfg["test_every"], "background": list(cfg["background"])}

    if cfg["model_source"] == "ply":
        return _import_ply(scene, scene_dir, out_dir, cfg, views, test_v, bg, stats, scene_id, t0)

    # ---- what the scene needs
    with timed("scene analysis", log, timings):
        if cfg["sh_degree"] == "auto":
            score = view_dependence(scene_dir / "sparse" / "0", scene_dir / IMAGES_DIR, seed=seed)
            sh_max = choose_sh_degree(score, cfg["sh_thresholds"])
        else:
            score, sh_max = None, int(cfg["sh_degree"])
        if cfg["budget"] == "auto":
            budget, edges = detail_budget([v.images[1].numpy() for v in train_v],
                                          cfg["budget_per_edge_pixel"], cfg["budget_min"], cfg["budget_max"])
        else:
            budget, edges = int(cfg["budget"]), None
    stats.update({"view_dependence": score, "sh_degree": sh_max, "budget": budget,
                  "median_edge_pixels": edges})
    log.info("scene needs: SH degree %d (view dependence %s), budget %d Gaussians",
             sh_max, "n/a" if score is None else f"{score:.3f}", budget)

    if scene.points_xyz is None:
        raise InputError(f"{scene_dir}: no points3d.npz to initialise Gaussians from")
    try:
        g0 = init_from_points(scene.points_xyz, scene.points_rgb, sh_degree=sh_max,
                              init_opacity=cfg["init_opacity"], min_points=cfg["min_points"])
    except InputError as exc:
        raise InputError(f"{scene_dir / 'points3d.npz'}: {exc} (splat.min_points)") from exc
    p = to_params(g0)
    lrs = {"means": position_lr(0, cfg, extent), "quats": cfg["lr_rotation"],
           "log_scales": cfg["lr_scaling"], "opacity_logits": cfg["lr_opacity"],
           "sh_dc": cfg["lr_sh_dc"], "sh_rest": cfg["lr_sh_rest"]}
    opt = Adam(lrs)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    dcfg = DensifyConfig(grad_threshold=cfg["densify_grad_threshold"], percent_dense=cfg["percent_dense"],
                         min_opacity=cfg["prune_min_opacity"], budget=budget)
    gstats = GradStats.zeros(p["means"].shape[0])
    order: list[int] = []  # views left in the current epoch (popped from the end)
    it0, curve, best, bad_evals, train_time, cpu_time = 0, [], -math.inf, 0, 0.0, 0.0

    ckpt_dir = Path(checkpoint_dir) if checkpoint_dir else out_dir.with_name(out_dir.name + ".ckpt")
    ckpt = ckpt_dir / "checkpoint.pt"
    chash = config_hash(cfg, scene_dir) + f"-{seed}"
    st = _load_checkpoint(ckpt) if resume else None
    if st is not None:
        if st.get("hash") == chash:
            p, it0, curve, best, bad_evals, train_time = (st["params"], st["iteration"], st["curve"],
                                                          st["best"], st["bad_evals"], st["train_time"])
            opt.load_state_dict(st["opt"])
            gen.set_state(st["gen"])
            rng.bit_generator.state = st["rng"]
            gstats, order = st["gstats"], st["order"]
            cpu_time = st.get("cpu_time", 0.0)
            log.info("resumed from %s at iteration %d", ckpt, it0)
        else:
            log.info("ignoring checkpoint %s (different config or seed)", ckpt)

    def save_checkpoint(n_it: int) -> None:
        ckpt_dir.mkdir(parents=True, exist_ok=True)
        with atomic_path(ckpt) as tmp:
            torch.save({"hash": chash, "params": p, "iteration": n_it, "curve": curve, "best": best,
                        "bad_evals": bad_evals, "train_time": time.perf_counter() - t_loop,
                        "cpu_time": time.process_time() - c_loop,
                        "opt": opt.state_dict(), "gen": gen.get_state(),
                        "rng": rng.bit_generator.state, "gstats": gstats, "order": order}, tmp)

    it = it0
    stop_reason = "max_iterations"
    bar = progress(range(it0, cfg["max_iterations"]), desc="training", total=cfg["max_iterations"],
                   initial=it0)
    t_loop = time.perf_counter() - train_time
    c_loop = time.process_time() - cpu_time  # CPU seconds (all threads): robust on a shared machine
    for it in bar:
        ds = downscale_at(schedule, it)
        sh_deg = min(sh_max, it // cfg["sh_increase_every"])
        opt.lrs["means"] = position_lr(it, cfg, extent)
        if not order:
            order = list(rng.permutation(len(train_v)))
        v = train_v[order.pop()]
        cam, gt = v.camera(ds)
        for k in PARAMS:
            p[k].requires_grad_(True)
        try:
            img, alpha, depth, meta = render(p, cam, bg, sh_deg, backend)
            loss = photometric_loss(img, gt, cfg["lambda_ssim"])
            loss.backward()
        except NonFiniteError as exc:
            raise NonFiniteError(f"{scene_dir}: training step {it + 1} (view {v.name}): {exc}; "
                                 "no output written") from exc
        grads = {k: p[k].grad for k in PARAMS}
        for k in PARAMS:
            p[k].requires_grad_(False)
            p[k].grad = None
        opt.step(p, grads)
        n_it = it + 1
        if n_it < cfg["densify_until"]:
            gstats.update(meta["grad2d"], meta["radii"], cam.width, cam.height, ds)
            if n_it >= cfg["densify_from"] and n_it % cfg["densify_every"] == 0:
                dcfg.prune_big = n_it > cfg["opacity_reset_every"]
                res = densify_and_prune(p, opt, gstats, dcfg, extent, gen)
                gstats = GradStats.zeros(p["means"].shape[0])
                log.debug("it %d densify: %s", n_it, res)
            if n_it % cfg["opacity_reset_every"] == 0:
                reset_opacity(p, opt)
                # the held-out PSNR drops and recovers: restart plateau tracking, or the
                # run would stop during the recovery with a model worse than before
                best, bad_evals = -math.inf, 0
        if n_it % cfg["eval_every"] == 0 or n_it == cfg["max_iterations"]:
            elapsed = time.perf_counter() - t_loop
            ev = evaluate(p, test_v or train_v[:4], bg, sh_deg, backend)
            curve.append({"iteration": n_it, "train_time_s": elapsed,
                          "cpu_time_s": time.process_time() - c_loop, "psnr": ev["psnr"],
                          "ssim": ev["ssim"], "n_gaussians": int(p["means"].shape[0]),
                          "downscale": ds, "loss": float(loss.detach())})
            log.info("it %d: held-out PSNR %.2f dB, SSIM %.4f, %d Gaussians, %.1f s", n_it,
                     ev["psnr"], ev["ssim"], p["means"].shape[0], elapsed)
            full_res = downscale_at(schedule, n_it) == 1
            if ev["psnr"] > best + cfg["plateau_min_delta_db"]:
                best, bad_evals = ev["psnr"], 0
            elif full_res:
                bad_evals += 1
            if full_res and n_it >= cfg["min_iterations"] and bad_evals >= cfg["plateau_patience"]:
                stop_reason = "plateau"
                break
        if interrupt_after is not None and n_it >= interrupt_after and n_it < cfg["max_iterations"]:
            save_checkpoint(n_it)
            if hasattr(bar, "close"):
                bar.close()
            log.info("interrupted after step %d; checkpoint %s", n_it, ckpt)
            return {"interrupted": True, "iteration": n_it, "checkpoint": str(ckpt)}
        if cfg["checkpoint_every"] and n_it % cfg["checkpoint_every"] == 0 and n_it < cfg["max_iterations"]:
            save_checkpoint(n_it)
    if hasattr(bar, "close"):
        bar.close()
    n_iters = it + 1 if cfg["max_iterations"] > it0 else it0
    train_s = time.perf_counter() - t_loop
    cpu_s = time.process_time() - c_loop
    sh_final = min(sh_max, max(0, n_iters - 1) // cfg["sh_increase_every"])
    final = evaluate(p, test_v, bg, sh_final, backend)
    stats.update({"source": "trained", "iterations": n_iters, "stop_reason": stop_reason,
                  "n_gaussians": int(p["means"].shape[0]), "train_time_s": train_s, "train_cpu_s": cpu_s,
                  "test_psnr": final["psnr"], "test_ssim": final["ssim"], "test_lpips": None,
                  "sh_degree_final": sh_final, **{f"time_{k.replace(' ', '_')}_s": t for k, t in timings.items()}})
    _write_model(out_dir, scene, from_params(p), n_iters, sh_final, stats, curve, scene_id, scene_dir)
    if ckpt.exists():
        ckpt.unlink()
    if ckpt_dir.is_dir():
        sweep_output(ckpt)  # a checkpoint write killed earlier
        try:
            ckpt_dir.rmdir()
        except OSError:
            pass
    stats["time_total_s"] = time.perf_counter() - t0
    log.info("trained %d iterations (%s): %d Gaussians, held-out PSNR %.2f dB SSIM %.4f, %.1f s",
             n_iters, stop_reason, stats["n_gaussians"], final["psnr"], final["ssim"], train_s)
    return stats


def _load_checkpoint(path: Path) -> dict | None:
    """The checkpoint at ``path``, or None if there is none or it cannot be read
    (it is only a shortcut: training then starts from the beginning)."""
    if not path.exists():
        return None
    try:
        st = torch.load(path, weights_only=False)
        if not isinstance(st, dict):
            raise ValueError(f"a {type(st).__name__}, not a checkpoint")
        return st
    except Exception as exc:  # truncated or foreign file: torch raises several types
        log.warning("ignoring unreadable checkpoint %s (%s); training from the start", path,
                    " ".join(str(exc).split())[:200])
        return None


def _write_model(out_dir: Path, scene: Scene, g: dict[str, np.ndarray], iterations: int,
                 sh_degree: int, stats: dict, curve: list[dict], scene_id: str | None,
                 scene_dir: Path) -> None:
    import pandas as pd

    from gs2e.metrics.table import write_metrics

    with atomic_dir(out_dir) as out:
        save_model(out, g, iterations, sh_degree, {
            "scene": str(scene_dir), "width": scene.width, "height": scene.height,
            "source": stats.get("source"), "background": stats["background"],
            "test_every": stats["test_every"]})
        write_cameras_json(out / "cameras.json", scene)
        write_json_atomic(out / "train_stats.json", stats)
        write_metrics(out / "metrics.parquet", stats, scene_id=scene_id or out_dir.parent.name,
                      stage="train")
        if curve:
            pd.DataFrame(curve).to_parquet(out / "curve.parquet", index=False)


def _import_ply(scene, scene_dir, out_dir, cfg, views, test_v, bg, stats, scene_id, t0):
    """Use a model trained elsewhere (official 3DGS, gsplat) instead of training."""
    path = cfg.get("ply_path")
    if not path:
        raise InputError("splat.model_source is 'ply' but splat.ply_path is not set")
    path = Path(path)
    iterations = None
    if path.is_dir():
        its = sorted(path.glob("point_cloud/iteration_*/point_cloud.ply"),
                     key=lambda q: int(q.parent.name.split("_")[1]))
        if not its:
            raise InputError(f"{path}: no point_cloud/iteration_*/point_cloud.ply")
        path = its[-1]
        iterations = int(path.parent.name.split("_")[1])
    g = read_ply(path)
    sh_deg = int(round(math.sqrt(g["sh"].shape[1]))) - 1
    p = to_params(g)
    ev = evaluate(p, test_v, bg, sh_deg, stats["backend"])
    stats.update({"source": "ply", "ply_path": str(path), "iterations": iterations,
                  "n_gaussians": int(len(g["means"])), "train_time_s": None,
                  "test_psnr": ev["psnr"], "test_ssim": ev["ssim"], "test_lpips": None,
                  "sh_degree": sh_deg, "sh_degree_final": sh_deg})
    _write_model(out_dir, scene, g, iterations or 0, sh_deg, stats, [], scene_id, scene_dir)
    stats["time_total_s"] = time.perf_counter() - t0
    return stats
