"""Adaptive density control (clone / split / prune / opacity reset), the
optimiser state that must follow it, and :class:`DensifyStrategy`, which owns
when each of them runs (the 3DGS schedule) so the trainer's loop only calls it.

Gaussian parameters are a dict of float tensors with the Gaussian index first:
``means (N,3)``, ``quats (N,4)``, ``log_scales (N,3)``, ``opacity_logits (N,)``,
``sh_dc (N,1,3)``, ``sh_rest (N,K-1,3)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import torch

from gs2e.common.log import get_logger
from gs2e.common.so3 import quat_to_rotmat
from gs2e.splat.settings import SplatSettings

log = get_logger("gs2e.splat")

PARAMS = ("means", "quats", "log_scales", "opacity_logits", "sh_dc", "sh_rest")


class Adam:
    """Adam over a dict of tensors whose rows can be selected and appended
    (what densification needs); new rows start with zero moments."""

    def __init__(self, lrs: dict[str, float], betas=(0.9, 0.999), eps: float = 1e-15):
        self.lrs = dict(lrs)
        self.b1, self.b2 = betas
        self.eps = eps
        self.t = 0
        self.m: dict[str, torch.Tensor] = {}
        self.v: dict[str, torch.Tensor] = {}

    def step(self, params: dict[str, torch.Tensor], grads: dict[str, torch.Tensor]) -> None:
        self.t += 1
        c1 = 1 - self.b1 ** self.t
        c2 = 1 - self.b2 ** self.t
        with torch.no_grad():
            for k, g in grads.items():
                if g is None:
                    continue
                p = params[k]
                if k not in self.m:
                    self.m[k] = torch.zeros_like(p)
                    self.v[k] = torch.zeros_like(p)
                m, v = self.m[k], self.v[k]
                m.mul_(self.b1).add_(g, alpha=1 - self.b1)
                v.mul_(self.b2).addcmul_(g, g, value=1 - self.b2)
                denom = (v / c2).sqrt_().add_(self.eps)
                p.addcdiv_(m, denom, value=-self.lrs[k] / c1)

    def select(self, keep: torch.Tensor) -> None:
        for d in (self.m, self.v):
            for k in d:
                d[k] = d[k][keep].contiguous()

    def append(self, n_new: int) -> None:
        for d in (self.m, self.v):
            for k in d:
                z = torch.zeros((n_new,) + tuple(d[k].shape[1:]), dtype=d[k].dtype)
                d[k] = torch.cat([d[k], z]).contiguous()

    def reset_rows(self, key: str) -> None:
        if key in self.m:
            self.m[key].zero_()
            self.v[key].zero_()

    def state_dict(self) -> dict:
        return {"t": self.t, "m": self.m, "v": self.v, "lrs": self.lrs}

    def load_state_dict(self, st: dict) -> None:
        self.t, self.m, self.v, self.lrs = st["t"], st["m"], st["v"], st["lrs"]


@dataclass
class GradStats:
    """Per-Gaussian screen-space gradient statistics between densifications."""

    grad_accum: torch.Tensor  # (N,) sum of NDC-gradient norms over views that saw it
    count: torch.Tensor       # (N,) number of such views
    max_radius_px: torch.Tensor  # (N,) largest screen radius seen (full-res px)

    @staticmethod
    def zeros(n: int) -> "GradStats":
        return GradStats(torch.zeros(n, dtype=torch.float64), torch.zeros(n, dtype=torch.float64),
                         torch.zeros(n, dtype=torch.float64))

    def update(self, grad2d_px: torch.Tensor, radii: torch.Tensor, width: int, height: int,
               downscale: float) -> None:
        vis = radii > 0
        g = grad2d_px.double()
        # gradient w.r.t. NDC coordinates (x_ndc = 2 x_px / W - 1): resolution independent
        gn = torch.sqrt((g[:, 0] * 0.5 * width) ** 2 + (g[:, 1] * 0.5 * height) ** 2)
        self.grad_accum[vis] += gn[vis]
        self.count[vis] += 1
        self.max_radius_px = torch.maximum(self.max_radius_px, radii.double() * downscale)

    def mean_grad(self) -> torch.Tensor:
        return self.grad_accum / self.count.clamp_min(1)


@dataclass
class DensifyConfig:
    grad_threshold: float = 2e-4
    percent_dense: float = 0.01
    min_opacity: float = 0.005
    max_screen_px: float = 20.0
    max_world_frac: float = 0.1
    split_n: int = 2
    budget: int = 1_000_000
    prune_big: bool = False
    log: dict = field(default_factory=dict)


def _quat_rotmat(q: torch.Tensor) -> torch.Tensor:
    """(N, 4) wxyz quaternions (any norm) -> (N, 3, 3), via gs2e.common.so3."""
    return torch.from_numpy(quat_to_rotmat(q.detach().double().numpy())).to(q.dtype)


def densify_and_prune(params: dict[str, torch.Tensor], opt: Adam, stats: GradStats,
                      cfg: DensifyConfig, extent: float, gen: torch.Generator) -> dict[str, int]:
    """One round of adaptive density control, in place on ``params`` and ``opt``.

    Candidates have mean NDC gradient > ``grad_threshold``; small ones (max
    scale <= percent_dense * extent) are cloned, large ones split into
    ``split_n`` samples drawn from the Gaussian with scales / (0.8 * split_n).
    When the candidates would exceed ``cfg.budget`` only the ones with the
    largest gradients are densified. Then Gaussians with opacity <
    ``min_opacity`` (and, if ``prune_big``, too large on screen or in the world)
    are removed. Returns counts of cloned, split and pruned Gaussians.
    """
    n = params["means"].shape[0]
    with torch.no_grad():
        g = stats.mean_grad()
        max_scale = params["log_scales"].exp().amax(dim=1).double()
        cand = g >= cfg.grad_threshold
        room = max(0, cfg.budget - n)
        n_split_candidates = int((cand & (max_scale > cfg.percent_dense * extent)).sum())
        n_clone_candidates = int(cand.sum()) - n_split_candidates
        # each clone adds 1, each split adds split_n - 1 Gaussians
        needed = n_clone_candidates + n_split_candidates * (cfg.split_n - 1)
        if needed > room:
            order = torch.argsort(torch.where(cand, g, torch.full_like(g, -1.0)), descending=True)
            is_split_sorted = (max_scale > cfg.percent_dense * extent)[order].long()
            cost = 1 + is_split_sorted * (cfg.split_n - 2)
            keep_n = int((torch.cumsum(cost, 0) <= room).sum())
            limited = torch.zeros_like(cand)
            limited[order[:keep_n]] = True
            cand = cand & limited
        clone = cand & (max_scale <= cfg.percent_dense * extent)
        split = cand & (max_scale > cfg.percent_dense * extent)

        new: dict[str, list[torch.Tensor]] = {k: [] for k in PARAMS}
        if clone.any():
            for k in PARAMS:
                new[k].append(params[k][clone].clone())
        n_split = int(split.sum())
        if n_split:
            s = params["log_scales"][split].exp()
            R = _quat_rotmat(params["quats"][split])
            for _ in range(cfg.split_n):
                eps = torch.randn((n_split, 3), generator=gen, dtype=s.dtype)
                offs = torch.einsum("nij,nj->ni", R, eps * s)
                new["means"].append(params["means"][split] + offs)
                new["log_scales"].append(torch.log(s / (0.8 * cfg.split_n)))
                for k in ("quats", "opacity_logits", "sh_dc", "sh_rest"):
                    new[k].append(params[k][split].clone())
        n_added = sum(t.shape[0] for t in new["means"])
        if n_added:
            for k in PARAMS:
                params[k] = torch.cat([params[k]] + new[k]).contiguous()
            opt.append(n_added)
        # remove split originals, low-opacity and (optionally) oversized Gaussians
        keep = torch.ones(n + n_added, dtype=torch.bool)
        keep[:n][split] = False
        opac = torch.sigmoid(params["opacity_logits"])
        low = opac < cfg.min_opacity
        keep &= ~low
        n_big = 0
        if cfg.prune_big:
            radius = torch.cat([stats.max_radius_px, torch.zeros(n_added, dtype=torch.float64)])
            big = (radius > cfg.max_screen_px) | (
                params["log_scales"].exp().amax(dim=1).double() > cfg.max_world_frac * extent)
            n_big = int((big & keep).sum())
            keep &= ~big
        if not keep.all():
            for k in PARAMS:
                params[k] = params[k][keep].contiguous()
            opt.select(keep)
    return {"cloned": int(clone.sum()), "split": n_split, "pruned": int((~keep).sum()) - n_split,
            "pruned_big": n_big, "n": int(params["means"].shape[0])}


def reset_opacity(params: dict[str, torch.Tensor], opt: Adam, max_opacity: float = 0.01) -> None:
    """Clamp opacities to ``max_opacity`` (3DGS's periodic reset) and zero their moments."""
    with torch.no_grad():
        cap = math.log(max_opacity / (1 - max_opacity))
        params["opacity_logits"].clamp_(max=cap)
    opt.reset_rows("opacity_logits")


@dataclass
class DensifyStrategy:
    """Density control on the 3DGS schedule (like gsplat's ``DefaultStrategy``).

    After each optimiser step, until ``densify_until``: accumulate the
    screen-space gradient statistics of the step's view; every
    ``densify_every`` steps from ``densify_from`` clone / split / prune
    (:func:`densify_and_prune` with ``ops``; Gaussians too large on screen or in
    the world are pruned too once the first opacity reset is past); every
    ``opacity_reset_every`` steps reset the opacities. Step counts are steps
    done (1 after the first step). The statistics are the strategy's state
    (``stats``), saved with checkpoints.
    """

    ops: DensifyConfig
    extent: float  # scene extent (world units): the scale of percent_dense and max_world_frac
    densify_from: int = 500
    densify_until: int = 15_000
    densify_every: int = 100
    opacity_reset_every: int = 3000
    stats: GradStats | None = None

    @classmethod
    def from_config(cls, cfg: SplatSettings, budget: int, extent: float) -> "DensifyStrategy":
        """The strategy of the ``splat`` settings ``cfg``."""
        ops = DensifyConfig(grad_threshold=cfg.densify_grad_threshold, percent_dense=cfg.percent_dense,
                            min_opacity=cfg.prune_min_opacity, budget=budget)
        return cls(ops, extent, densify_from=cfg.densify_from, densify_until=cfg.densify_until,
                   densify_every=cfg.densify_every, opacity_reset_every=cfg.opacity_reset_every)

    def step_post_update(self, params: dict[str, torch.Tensor], opt: Adam, step: int, meta: dict,
                         width: int, height: int, downscale: int, gen: torch.Generator) -> bool:
        """Run what the schedule holds after optimiser step number ``step``, in
        place on ``params`` and ``opt``. ``meta`` is the step's render
        metadata (``grad2d`` (N, 2) px, ``radii`` (N,)) at ``width`` x
        ``height`` px, ``downscale`` the factor of that resolution; ``gen``
        draws the split samples. Returns True when the opacities were reset
        (the held-out PSNR dips and recovers after that)."""
        if step >= self.densify_until:
            return False
        if self.stats is None:
            self.stats = GradStats.zeros(params["means"].shape[0])
        self.stats.update(meta["grad2d"], meta["radii"], width, height, downscale)
        if step >= self.densify_from and step % self.densify_every == 0:
            ops = replace(self.ops, prune_big=step > self.opacity_reset_every)
            res = densify_and_prune(params, opt, self.stats, ops, self.extent, gen)
            self.stats = GradStats.zeros(params["means"].shape[0])
            log.debug("it %d densify: %s", step, res)
        if step % self.opacity_reset_every == 0:
            reset_opacity(params, opt)
            return True
        return False


@dataclass
class GrowingBudget:
    """A Gaussian budget that grows while held-out quality pays for it.

    Starts at ``budget`` (the caller floors it at the initial Gaussian count,
    the SfM points). At each held-out evaluation while densification runs
    (:meth:`update`): if the count has reached the budget, the budget grows by
    ``growth`` (at most ``budget_max``). The growth is judged once the count
    has filled the new room and one more evaluation has passed, on the better
    of those two evaluations: one evaluation can dip (1.9 dB on temple_ring
    when evaluations still followed a densification step), and judging on a
    dip would end growth that pays. If the better PSNR is not at least ``min_gain_db`` above
    the PSNR at the growth, the budget is frozen at the count reached (never
    below ``floor``) for the rest of the run; otherwise it may grow again at
    once, from that better PSNR. A resolution change restarts the comparison
    from the new resolution's first evaluation (its jump is not the Gaussians'
    doing). The gain is measured with training continuing, so it credits the
    added Gaussians with what more steps alone would also give: a generous
    test, which ``min_gain_db`` offsets. ``history`` lists (step, budget,
    held-out PSNR, event) for the statistics.
    """

    budget: int
    budget_max: int
    growth: float = 1.5
    min_gain_db: float = 0.1
    floor: int = 1  # never frozen below this count (the SfM points)
    frozen: bool = False
    since: tuple[float, int] | None = None  # (PSNR dB, downscale) at the last growth
    settled: int = 0  # evaluations since the count filled the last growth's room
    best_db: float = -math.inf  # the best held-out PSNR among those

    history: list = field(default_factory=list)

    def update(self, step: int, psnr: float, downscale: int, n_gaussians: int) -> int:
        """The budget after a held-out evaluation at ``step`` (call only while
        densification runs)."""
        if self.frozen:
            return self.budget
        full = n_gaussians >= 0.95 * self.budget
        base = psnr
        if self.since is not None:
            psnr0, ds0 = self.since
            if ds0 != downscale:
                self.since, self.settled, self.best_db = (psnr, downscale), 0, -math.inf
                return self.budget
            if self.settled == 0 and not full:
                return self.budget  # the new room is still filling
            self.settled += 1
            self.best_db = max(self.best_db, psnr)
            if self.settled < 2:
                return self.budget  # filled: one more evaluation before the verdict
            if self.best_db - psnr0 < self.min_gain_db:
                self.frozen = True
                self.budget = max(n_gaussians, self.floor)
                self.history.append((step, self.budget, psnr, "frozen"))
                return self.budget
            base = self.best_db
            self.since, self.settled, self.best_db = None, 0, -math.inf
        if full and self.budget < self.budget_max:
            self.budget = min(self.budget_max, int(math.ceil(self.budget * self.growth)))
            self.since = (base, downscale)
            self.history.append((step, self.budget, psnr, "grown"))
        return self.budget

    def summary(self) -> dict:
        """What the training statistics record: the final budget, how often
        it grew and the step where it froze (None: never)."""
        frozen = [h[0] for h in self.history if h[3] == "frozen"]
        return {"budget": int(self.budget), "budget_growths": sum(h[3] == "grown" for h in self.history),
                "budget_frozen_at": frozen[0] if frozen else None}
