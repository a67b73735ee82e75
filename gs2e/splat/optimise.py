"""One optimisation loop for every objective a Gaussian model is trained on.

An objective (:class:`Objective`) says what one step's loss is: it renders
what it needs through :func:`gs2e.splat.model.render` and returns the loss
with the render whose screen-space gradients drive densification. The loop
(:func:`optimise`) owns everything else, the same for ``gs2e train``'s
photometric objective and the benchmark's event-supervised ones
(:mod:`gs2e.bench.recon3d`): the position learning rate's log-linear decay, the
coarse-to-fine downscale schedule, the SH degree ramp, backward and Adam
(:func:`apply_loss`), the non-finite guard naming the step, densification by
the strategy object, and the progress bar. What only one caller needs
(held-out evaluation, plateau stop, checkpoints) comes in as two hooks.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol

import torch

from gs2e.common.progress import progress
from gs2e.splat.rasterize import NonFiniteError, SplatCamera
from gs2e.splat.settings import SplatSettings
from gs2e.splat.strategy import PARAMS, Adam, DensifyStrategy


class Step(NamedTuple):
    """One step's loss and the render that densification reads (its ``meta``:
    radii, 2D-mean gradients) with that render's camera (a tuple, loss first,
    as :func:`gradient_step` takes it)."""

    loss: torch.Tensor
    meta: dict
    cam: SplatCamera


class Objective(Protocol):
    """What a training run minimises, one step at a time."""

    def step(self, p: dict[str, torch.Tensor], it: int, downscale: int, sh_degree: int) -> Step:
        """The loss of step ``it`` (0-based) at image downscale ``downscale``
        and SH degree ``sh_degree``; ``p`` requires grad."""

    def where(self) -> str:
        """What the last step used (a view, a time window), for error messages."""


@dataclass(frozen=True)
class Schedule:
    """The loop's schedules. ``steps``: the last step (exclusive); position
    lr decays log-linearly from ``lr_position_init`` to ``lr_position_final``
    (times the scene extent) over ``steps``; ``resolution``: [[from_step,
    downscale], ...]; the SH degree rises by one every ``sh_increase_every``
    steps up to ``sh_degree``."""

    steps: int
    lr_position_init: float
    lr_position_final: float
    resolution: tuple = ((0, 1),)
    sh_degree: int = 0
    sh_increase_every: int = 1000

    def position_lr(self, it: int, extent: float) -> float:
        t = min(1.0, it / max(1, self.steps))
        lo, hi = self.lr_position_final, self.lr_position_init
        return extent * math.exp((1 - t) * math.log(hi) + t * math.log(lo))

    def downscale(self, it: int) -> int:
        return downscale_at(self.resolution, it)

    def sh_degree_at(self, it: int) -> int:
        return min(self.sh_degree, it // self.sh_increase_every)


def downscale_at(schedule, it: int) -> int:
    """Downscale factor of the coarse-to-fine ``schedule`` [[from_step, factor], ...] at step ``it``."""
    d = 1
    for start, factor in sorted(schedule):
        if it >= start:
            d = int(factor)
    return d


# compute_dtype auto: float32 from here, the smallest training size at which it
# was measured to keep held-out PSNR (the demo's 255x191; docs/train.md)
F32_TRAIN_MIN_PIXELS = 45_000


def training_dtype(compute_dtype: str, train_size: tuple[int, int]) -> str:
    """What the training passes compute in: ``splat.compute_dtype``, with
    ``auto`` resolved by the training size (W, H) px: float32 (16 lanes, fused
    multiply-adds, an exp without a table: 1.4-1.6x faster steps on AVX2 at
    320 px, held-out PSNR within 0.2 dB of float64's at the demo's size, 320 px
    and DAVIS346, within the seeds' spread at HD) where the views have at least
    F32_TRAIN_MIN_PIXELS pixels, float64 below, where float32's quality was not
    measured."""
    if compute_dtype != "auto":
        return compute_dtype
    return "float32" if train_size[0] * train_size[1] >= F32_TRAIN_MIN_PIXELS else "float64"


def make_optimizer(lrs: SplatSettings, sched: Schedule, extent: float) -> Adam:
    """Adam with the per-parameter learning rates of the ``splat`` settings
    ``lrs`` (``lr_rotation``, ``lr_scaling``, ``lr_opacity``, ``lr_sh_dc``,
    ``lr_sh_rest``) and the position lr of step 0."""
    return Adam({"means": sched.position_lr(0, extent), "quats": lrs.lr_rotation,
                 "log_scales": lrs.lr_scaling, "opacity_logits": lrs.lr_opacity,
                 "sh_dc": lrs.lr_sh_dc, "sh_rest": lrs.lr_sh_rest})


def apply_loss(p: dict[str, torch.Tensor], opt: Adam, loss: torch.Tensor) -> None:
    """Backward of ``loss`` to the parameters ``p`` (which require grad), one
    Adam step on them, and the parameters left without grad state."""
    loss.backward()
    grads = {k: p[k].grad for k in PARAMS}
    for k in PARAMS:
        p[k].requires_grad_(False)
        p[k].grad = None
    opt.step(p, grads)


def gradient_step(p: dict[str, torch.Tensor], opt: Adam, loss_of: Callable[[], tuple]) -> tuple:
    """``loss_of()`` with ``p`` requiring grad (it returns the loss first), then
    :func:`apply_loss`; returns what ``loss_of`` returned."""
    for k in PARAMS:
        p[k].requires_grad_(True)
    out = loss_of()
    apply_loss(p, opt, out[0])
    return out


def optimise(p: dict[str, torch.Tensor], opt: Adam, strategy: DensifyStrategy,
             objective: Objective, sched: Schedule, extent: float, gen: torch.Generator,
             start: int = 0, before_densify: Callable[[int, Step, int, int], bool] | None = None,
             after_step: Callable[[int, bool], bool] | None = None, desc: str = "training",
             context: str = "") -> int:
    """Run steps ``start`` .. ``sched.steps - 1`` of ``objective`` on ``p``
    (updated in place); returns the number of steps done in all.

    Per step: position lr, downscale and SH degree from ``sched``; the
    objective's loss; backward and Adam; ``before_densify(n, step, downscale,
    sh_degree)`` (n = steps done; True stops the run before densifying); the
    strategy's densification (not after the last step: its Gaussians would go
    out untrained); ``after_step(n, densified)`` (True stops the run). A
    non-finite parameter or gradient raises NonFiniteError naming ``context``,
    the step and :meth:`Objective.where`.
    """
    n = start
    bar = progress(range(start, sched.steps), desc=desc, total=sched.steps, initial=start)
    try:
        for it in bar:
            ds, sh = sched.downscale(it), sched.sh_degree_at(it)
            opt.lrs["means"] = sched.position_lr(it, extent)
            try:
                step = gradient_step(p, opt, lambda: objective.step(p, it, ds, sh))
            except NonFiniteError as exc:
                raise NonFiniteError(f"{context}training step {it + 1} ({objective.where()}): {exc}; "
                                     "no output written") from exc
            n = it + 1
            if before_densify is not None and before_densify(n, step, ds, sh):
                break
            densified = n < sched.steps and strategy.step_post_update(
                p, opt, n, step.meta, step.cam.width, step.cam.height, ds, gen)
            if after_step is not None and after_step(n, bool(densified)):
                break
    finally:
        if hasattr(bar, "close"):
            bar.close()
    return n
