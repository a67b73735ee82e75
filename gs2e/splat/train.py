"""3D Gaussian Splatting training on the CPU.

Follows the official recipe (Adam with per-parameter learning rates, position
lr decaying log-linearly, 0.8 L1 + 0.2 (1 - SSIM), clone/split/prune, opacity
reset, SH degree schedule, every ``test_every``-th view held out) and adds what
makes it cheap on a CPU: a coarse-to-fine resolution schedule, a Gaussian
budget measured from image detail (or, with ``budget: adaptive``, grown from
there while held-out PSNR pays for it), an SH degree chosen from the view
dependence the SfM tracks show, and early stopping when held-out PSNR
plateaus. Checkpoints allow resuming an interrupted run.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from gs2e.common.errors import InputError
from gs2e.common.log import get_logger, timed
from gs2e.common.settings import require
from gs2e.common.threads import set_threads
from gs2e.io.scene import IMAGES_DIR, Scene, read_scene
from gs2e.splat.backend import resolve_backend_for
from gs2e.splat.checkpoint import Checkpoint
from gs2e.splat.evaluate import evaluate
from gs2e.splat.import_ply import import_ply
from gs2e.splat.init import init_from_points
from gs2e.splat.loss import photometric_loss
from gs2e.splat.model import from_params, render, to_params
from gs2e.splat.optimise import (Schedule, Step, downscale_at, gradient_step, make_optimizer,
                                 optimise, training_dtype)
from gs2e.splat.output import write_train_output
from gs2e.splat.scene_stats import choose_sh_degree, detail_budget, view_dependence
from gs2e.splat.settings import SplatSettings
from gs2e.splat.strategy import Adam, DensifyStrategy, GrowingBudget
from gs2e.splat.views import View, load_views, scene_extent, split_views, train_sizes

log = get_logger("gs2e.splat")

__all__ = ["train"]


def plateau_step(best: float, bad_evals: int, psnr: float, n_it: int,
                 cfg: SplatSettings) -> tuple[float, int, bool]:
    """One held-out evaluation (PSNR dB, after n_it steps) of the plateau stop:
    the new (best, bad_evals) and whether training stops. An evaluation that does
    not beat the best by ``plateau_min_delta_db`` counts against the run only at
    full resolution; the stop comes after ``plateau_patience`` such in a row,
    from ``min_iterations`` on. (``benchmarks/bench_train_budget.py`` replays it
    on recorded curves.)"""
    full_res = downscale_at(cfg.resolution_schedule, n_it) == 1
    if psnr > best + cfg.plateau_min_delta_db:
        best, bad_evals = psnr, 0
    elif full_res:
        bad_evals += 1
    return best, bad_evals, full_res and n_it >= cfg.min_iterations and bad_evals >= cfg.plateau_patience


def scene_needs(scene_dir: Path, train_v: list[View], cfg: SplatSettings, seed: int) -> dict[str, Any]:
    """SH degree and Gaussian budget of the scene (``auto``: measured from the
    SfM tracks' view dependence and the training images' detail; ``adaptive``
    starts from the same budget)."""
    if cfg.sh_degree == "auto":
        score = view_dependence(scene_dir / "sparse" / "0", scene_dir / IMAGES_DIR, seed=seed)
        sh_max = choose_sh_degree(score, cfg.sh_thresholds)
    else:
        score, sh_max = None, int(cfg.sh_degree)
    if cfg.budget in ("auto", "adaptive"):
        budget, edges = detail_budget([v.images[1].numpy() for v in train_v],
                                      cfg.budget_per_edge_pixel, cfg.budget_min, cfg.budget_max)
    else:
        budget, edges = int(cfg.budget), None
    return {"view_dependence": score, "sh_degree": sh_max, "budget": budget, "median_edge_pixels": edges}


def initial_params(scene: Scene, scene_dir: Path, cfg: SplatSettings, sh_degree: int) -> dict[str, torch.Tensor]:
    """Gaussians initialised from the scene's SfM points."""
    if scene.points_xyz is None:
        raise InputError(f"{scene_dir}: no points3d.npz to initialise Gaussians from")
    try:
        g0 = init_from_points(scene.points_xyz, scene.points_rgb, sh_degree=sh_degree,
                              init_opacity=cfg.init_opacity, min_points=cfg.min_points)
    except InputError as exc:
        raise InputError(f"{scene_dir / 'points3d.npz'}: {exc} (splat.min_points)") from exc
    return to_params(g0)


def photometric_step(p: dict[str, torch.Tensor], cam, gt: torch.Tensor, bg: torch.Tensor,
                     sh_degree: int, backend: str, compute_dtype: str, lambda_ssim: float,
                     window: str = "cut"):
    """Render one view and its photometric loss against ``gt``: (loss, the
    render's meta: radii, 2D-mean gradients for densification)."""
    img, _, _, meta = render(p, cam, bg, sh_degree, backend, compute_dtype, window)
    return photometric_loss(img, gt, lambda_ssim), meta


def train_step(p: dict[str, torch.Tensor], opt: Adam, cam, gt: torch.Tensor, bg: torch.Tensor,
               sh_degree: int, backend: str, compute_dtype: str, lambda_ssim: float,
               window: str = "cut"):
    """One optimiser step on one view (:func:`photometric_step`, backward,
    Adam; ``p`` updated in place): what a step of :func:`train` does, for
    benchmarks. Returns (loss, meta)."""
    return gradient_step(p, opt, lambda: photometric_step(p, cam, gt, bg, sh_degree, backend,
                                                          compute_dtype, lambda_ssim, window))


class PhotometricObjective:
    """``gs2e train``'s objective: each step one training view, in a random
    order per epoch (``rng``; ``order`` holds the views left in the epoch,
    popped from the end, and is part of a checkpoint), 0.8 L1 + 0.2 D-SSIM
    (``lambda_ssim``) against its photo at the step's downscale."""

    def __init__(self, views: list[View], rng: np.random.Generator, bg: torch.Tensor, backend: str,
                 compute_dtype: str, lambda_ssim: float, order: list[int] | None = None,
                 window: str = "cut"):
        self.views, self.rng, self.bg, self.window = views, rng, bg, window
        self.backend, self.compute_dtype, self.lambda_ssim = backend, compute_dtype, lambda_ssim
        self.order = list(order or [])
        self.view: View | None = None

    def step(self, p, it: int, downscale: int, sh_degree: int) -> Step:
        if not self.order:
            self.order = list(self.rng.permutation(len(self.views)))
        self.view = self.views[self.order.pop()]
        cam, gt = self.view.camera(downscale)
        loss, meta = photometric_step(p, cam, gt, self.bg, sh_degree, self.backend,
                                      self.compute_dtype, self.lambda_ssim, self.window)
        return Step(loss, meta, cam)

    def where(self) -> str:
        return f"view {self.view.name}" if self.view is not None else "no view yet"


class _Run:
    """What :func:`train` adds to the loop (:func:`optimise`) as its hooks:
    held-out evaluation before each step's densification, the plateau stop,
    the adaptive budget, checkpoints and interruption; and the state they
    keep, which a checkpoint holds with the loop's (parameters, Adam, random
    states, densification statistics, the views left in the epoch)."""

    def __init__(self, cfg, p, opt, gen, rng, strategy, objective, growing, ckpt, eval_views,
                 bg, backend, interrupt_after):
        self.cfg, self.p, self.opt, self.gen, self.rng = cfg, p, opt, gen, rng
        self.strategy, self.objective, self.growing, self.ckpt = strategy, objective, growing, ckpt
        self.eval_views, self.bg, self.backend = eval_views, bg, backend
        self.interrupt_after = interrupt_after
        self.curve: list[dict] = []
        self.best, self.bad_evals = -math.inf, 0
        self.stop_reason, self.interrupted = "max_iterations", False
        self._clock(0.0, 0.0)

    def _clock(self, train_time: float, cpu_time: float) -> None:
        self.t_loop = time.perf_counter() - train_time
        self.c_loop = time.process_time() - cpu_time  # CPU seconds (all threads): robust on a shared machine

    def elapsed(self) -> tuple[float, float]:
        """Wall and CPU seconds of training, resumed runs' included."""
        return time.perf_counter() - self.t_loop, time.process_time() - self.c_loop

    def resume(self) -> int:
        """Load the checkpoint if there is one; the step to continue from."""
        st = self.ckpt.load()
        if st is None:
            self._clock(0.0, 0.0)
            return 0
        self.p, self.curve, self.best, self.bad_evals = st["params"], st["curve"], st["best"], st["bad_evals"]
        self.opt.load_state_dict(st["opt"])
        self.gen.set_state(st["gen"])
        self.rng.bit_generator.state = st["rng"]
        self.strategy.stats, self.objective.order = st["gstats"], list(st["order"])
        if self.growing is not None:
            self.growing = st["budget"]
            self.strategy.ops.budget = self.growing.budget
        self._clock(st["train_time"], st.get("cpu_time", 0.0))
        log.info("resumed from %s at iteration %d", self.ckpt.path, st["iteration"])
        return int(st["iteration"])

    def save(self, n_it: int) -> None:
        train_time, cpu_time = self.elapsed()
        self.ckpt.save({"params": self.p, "iteration": n_it, "curve": self.curve, "best": self.best,
                        "bad_evals": self.bad_evals, "train_time": train_time, "cpu_time": cpu_time,
                        "opt": self.opt.state_dict(), "gen": self.gen.get_state(),
                        "rng": self.rng.bit_generator.state, "gstats": self.strategy.stats,
                        "order": self.objective.order, "budget": self.growing})

    def evaluate_and_stop(self, n_it: int, step: Step, ds: int, sh_deg: int) -> bool:
        # evaluate before this step's densification: a model with freshly split or
        # cloned Gaussians scores 1.5-2 dB lower for one evaluation (temple_ring),
        # which misled the plateau stop and the adaptive budget every other time
        cfg, p = self.cfg, self.p
        if not (n_it % cfg.eval_every == 0 or n_it == cfg.max_iterations):
            return False
        elapsed, cpu = self.elapsed()
        ev = evaluate(p, self.eval_views, self.bg, sh_deg, self.backend, self.cfg.window)
        self.curve.append({"iteration": n_it, "train_time_s": elapsed, "cpu_time_s": cpu,
                           "psnr": ev["psnr"], "ssim": ev["ssim"], "n_gaussians": int(p["means"].shape[0]),
                           "budget": int(self.strategy.ops.budget), "downscale": ds,
                           "loss": float(step.loss.detach())})
        log.info("it %d: held-out PSNR %.2f dB, SSIM %.4f, %d Gaussians, %.1f s", n_it,
                 ev["psnr"], ev["ssim"], p["means"].shape[0], elapsed)
        if self.growing is not None and cfg.densify_from <= n_it < cfg.densify_until:
            self.strategy.ops.budget = self.growing.update(n_it, ev["psnr"], ds, int(p["means"].shape[0]))
        self.best, self.bad_evals, stop = plateau_step(self.best, self.bad_evals, ev["psnr"], n_it, cfg)
        if stop:
            self.stop_reason = "plateau"
        return stop

    def after_step(self, n_it: int, densified: bool) -> bool:
        cfg = self.cfg
        if densified:
            # the held-out PSNR drops and recovers: restart plateau tracking, or the
            # run would stop during the recovery with a model worse than before
            self.best, self.bad_evals = -math.inf, 0
        last = n_it >= cfg.max_iterations
        if self.interrupt_after is not None and n_it >= self.interrupt_after and not last:
            self.save(n_it)
            self.interrupted = True
            return True
        if cfg.checkpoint_every and n_it % cfg.checkpoint_every == 0 and not last:
            self.save(n_it)
        return False


# ----------------------------------------------------------------- training
def _split_stats(views: list[View], train_v: list[View], test_v: list[View], extent: float,
                 cfg: SplatSettings, train_size: tuple[int, int]) -> dict[str, Any]:
    """The training statistics that describe the views and their split."""
    return {"n_views": len(views), "n_train_views": len(train_v), "n_test_views": len(test_v),
            "extent": extent, "test_every": cfg.test_every, "background": list(cfg.background),
            "train_width": train_size[0], "train_height": train_size[1]}


def densify_strategy(cfg: SplatSettings, budget: int, n_points: int,
                     extent: float) -> tuple[DensifyStrategy, GrowingBudget | None]:
    """The densification strategy of ``cfg`` for a scene whose detail asks
    for ``budget`` Gaussians, starting from ``n_points`` SfM points, and with
    ``budget: adaptive`` the budget that grows with held-out gains (from the
    detail budget, never below the SfM points; None otherwise)."""
    strategy = DensifyStrategy.from_config(cfg, budget, extent)
    if cfg.budget != "adaptive":
        return strategy, None
    growing = GrowingBudget(max(budget, n_points), cfg.budget_max, cfg.budget_growth,
                            cfg.budget_min_gain_db, floor=n_points)
    strategy.ops.budget = growing.budget
    return strategy, growing


def train(scene_dir: str | Path, out_dir: str | Path, cfg: SplatSettings, seed: int = 0,
          threads: int | None = None, scene_id: str | None = None,
          checkpoint_dir: str | Path | None = None, resume: bool = True,
          interrupt_after: int | None = None,
          target_size: tuple[int, int] | None = None) -> dict[str, Any]:
    """Train (or, with ``model_source: ply``, import) a Gaussian model of the
    scene in ``scene_dir`` (an sfm output: PINHOLE views with poses and
    points3d.npz; its ``sparse/0`` tracks are used to choose the SH degree)
    with the ``splat`` settings ``cfg``.

    Writes atomically to ``out_dir``: ``point_cloud/iteration_N/point_cloud.ply``
    (official layout), ``cameras.json``, ``model.json`` (what downstream stages
    read), ``train_stats.json``, ``metrics.parquet`` (one row) and
    ``curve.parquet`` (held-out PSNR/SSIM against wall time and iteration).
    Checkpoints go to ``checkpoint_dir`` (default ``<out_dir>.ckpt``) and are
    resumed when their config and seed match; they are removed after success.
    A resumed run continues exactly where the interrupted one stopped (view
    order, densification statistics, random states), so it writes the same
    model bytes as an uninterrupted run.

    ``target_size``: (W, H) of the largest image the outputs need (the event
    sensor's array): with ``max_side: auto`` the views train at the smallest
    size that covers it (:func:`gs2e.splat.views.train_sizes`).

    ``interrupt_after``: stop after that many steps in total, leaving a
    checkpoint and writing no output (time-sliced jobs; tests of resume).
    Returns the statistics (``{"interrupted": True, "iteration": N}`` then).

    Raises InputError (naming the file) for unusable scenes and
    NonFiniteError (naming the iteration and view) when parameters or
    gradients become NaN/inf; no output is written then.
    """
    cfg = require(cfg, SplatSettings, "train")
    scene_dir, out_dir = Path(scene_dir), Path(out_dir)
    backend = resolve_backend_for(cfg.backend, cfg.window)
    set_threads(threads)
    scene = read_scene(scene_dir)
    t0 = time.perf_counter()
    train_size, sizes = train_sizes(scene, cfg.max_side, target_size)
    views = load_views(scene_dir, scene, [1] + [int(f) for _, f in cfg.resolution_schedule], sizes)
    train_v, test_v = split_views(views, cfg.test_every)
    extent = scene_extent(train_v)
    bg = torch.tensor(cfg.background, dtype=torch.float32)
    timings: dict[str, float] = {}
    compute_dtype = training_dtype(cfg.compute_dtype, train_size)
    stats: dict[str, Any] = {"backend": backend, "compute_dtype": compute_dtype, "window": cfg.window,
                             **_split_stats(views, train_v, test_v, extent, cfg, train_size)}
    view_sizes = {v.name: list(sz) for v, sz in zip(views, sizes)}
    log.info("training at %dx%d (views %dx%d%s), passes in %s", *train_size, scene.width, scene.height,
             "" if target_size is None else f", event sensor {target_size[0]}x{target_size[1]}",
             compute_dtype)

    if cfg.model_source == "ply":
        stats = import_ply(cfg.ply_path, scene, scene_dir, out_dir, test_v, bg, stats, scene_id, view_sizes)
        stats["time_total_s"] = time.perf_counter() - t0
        return stats

    with timed("scene analysis", log, timings):
        needs = scene_needs(scene_dir, train_v, cfg, seed)
    stats.update(needs)
    sh_max = needs["sh_degree"]
    log.info("scene needs: SH degree %d (view dependence %s), budget %d Gaussians", sh_max,
             "n/a" if needs["view_dependence"] is None else f"{needs['view_dependence']:.3f}", needs["budget"])

    # ---- the loop's state: everything a checkpoint holds
    sched = Schedule(cfg.max_iterations, cfg.lr_position_init, cfg.lr_position_final,
                     cfg.resolution_schedule, sh_max, cfg.sh_increase_every)
    p = initial_params(scene, scene_dir, cfg, sh_max)
    strategy, growing = densify_strategy(cfg, needs["budget"], int(p["means"].shape[0]), extent)
    rng = np.random.default_rng(seed)  # view order
    run = _Run(cfg, p, make_optimizer(cfg, sched, extent), torch.Generator().manual_seed(seed), rng,
               strategy, PhotometricObjective(train_v, rng, bg, backend, compute_dtype,
                                              cfg.lambda_ssim, window=cfg.window),
               growing, Checkpoint(checkpoint_dir or out_dir.with_name(out_dir.name + ".ckpt"),
                                   {**cfg.as_dict(), "view_sizes": view_sizes}, scene_dir, seed),
               test_v or train_v[:4], bg, backend, interrupt_after)
    it0 = run.resume() if resume else 0
    n_iters = optimise(run.p, run.opt, strategy, run.objective, sched, extent, run.gen, start=it0,
                       before_densify=run.evaluate_and_stop, after_step=run.after_step,
                       context=f"{scene_dir}: ")
    if run.interrupted:
        log.info("interrupted after step %d; checkpoint %s", n_iters, run.ckpt.path)
        return {"interrupted": True, "iteration": n_iters, "checkpoint": str(run.ckpt.path)}
    p, growing, curve, stop_reason = run.p, run.growing, run.curve, run.stop_reason
    train_s, cpu_s = run.elapsed()
    sh_final = min(sh_max, max(0, n_iters - 1) // cfg.sh_increase_every)
    final = evaluate(p, test_v, bg, sh_final, backend, cfg.window)
    if growing is not None:
        stats.update(growing.summary())
    stats.update({"source": "trained", "iterations": n_iters, "stop_reason": stop_reason,
                  "n_gaussians": int(p["means"].shape[0]), "train_time_s": train_s, "train_cpu_s": cpu_s,
                  "test_psnr": final["psnr"], "test_ssim": final["ssim"], "test_lpips": None,
                  "sh_degree_final": sh_final, **{f"time_{k.replace(' ', '_')}_s": t for k, t in timings.items()}})
    write_train_output(out_dir, scene, from_params(p), n_iters, sh_final, stats, curve, scene_id, scene_dir,
                       view_sizes)
    run.ckpt.remove()
    stats["time_total_s"] = time.perf_counter() - t0
    log.info("trained %d iterations (%s): %d Gaussians, held-out PSNR %.2f dB SSIM %.4f, %.1f s",
             n_iters, stop_reason, stats["n_gaussians"], final["psnr"], final["ssim"], train_s)
    return stats
