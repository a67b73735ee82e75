"""The shared optimisation loop (gs2e.splat.optimise) with toy objectives: an
objective written against the public interface alone trains, densifies on its
schedule, is guarded against non-finite values (the error names the step and
what the objective used), and stops where a hook says."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gs2e.splat.init import init_from_points
from gs2e.splat.loss import photometric_loss
from gs2e.splat.model import render, to_params
from gs2e.splat.optimise import Schedule, Step, make_optimizer, optimise
from gs2e.splat.settings import SplatSettings
from gs2e.splat.rasterize import NonFiniteError
from gs2e.splat.strategy import DensifyConfig, DensifyStrategy
from splat_scenes import look_at_camera

LRS = SplatSettings.defaults(lr_rotation=1e-3, lr_scaling=5e-3, lr_opacity=0.025, lr_sh_dc=2.5e-3,
                             lr_sh_rest=1.25e-4)


def _model(n=200, seed=0, grey=128):
    rng = np.random.default_rng(seed)
    xyz = rng.uniform(-1, 1, (n, 3))
    rgb = np.full((n, 3), grey, np.uint8) if grey is not None else rng.integers(0, 255, (n, 3), np.uint8)
    return to_params(init_from_points(xyz, rgb, sh_degree=0, init_opacity=0.5))


class ToyTarget:
    """Fit one view of a fixed coloured model (not a gs2e objective: a user's)."""

    def __init__(self, cam):
        self.cam = cam
        with torch.no_grad():
            self.target = render(_model(grey=None, seed=1), cam, torch.zeros(3), 0)[0]
        self.calls: list[tuple[int, int]] = []

    def step(self, p, it, downscale, sh_degree):
        self.calls.append((it, downscale))
        img, _, _, meta = render(p, self.cam, torch.zeros(3), sh_degree)
        return Step(photometric_loss(img, self.target), meta, self.cam)

    def where(self):
        return "the toy view"


def _run(objective, steps, **kw):
    p = _model()
    sched = Schedule(steps, 1.6e-4, 1.6e-6)
    strategy = DensifyStrategy(DensifyConfig(grad_threshold=1e-6, budget=400), 1.0, densify_from=10,
                               densify_until=40, densify_every=10, opacity_reset_every=10 ** 9)
    n = optimise(p, make_optimizer(LRS, sched, 1.0), strategy, objective, sched, 1.0,
                 torch.Generator().manual_seed(0), **kw)
    return p, n


def test_a_toy_objective_trains_and_densifies_on_the_loop():
    cam = look_at_camera(48, 36)
    toy = ToyTarget(cam)
    losses = []
    p, n = _run(toy, 60, before_densify=lambda n, step, ds, sh: losses.append(float(step.loss.detach())) or False)
    assert n == 60 and [c[0] for c in toy.calls] == list(range(60))
    assert np.mean(losses[-5:]) < 0.8 * np.mean(losses[:5])
    assert 200 < p["means"].shape[0] <= 400, "densified within the budget"


def test_hooks_stop_the_run_and_the_schedule_reaches_the_objective():
    toy = ToyTarget(look_at_camera(48, 36))
    p = _model()
    sched = Schedule(30, 1.6e-4, 1.6e-6, resolution=((0, 2), (5, 1)))
    strategy = DensifyStrategy(DensifyConfig(budget=400), 1.0)
    n = optimise(p, make_optimizer(LRS, sched, 1.0), strategy, toy, sched, 1.0,
                 torch.Generator().manual_seed(0), after_step=lambda n, densified: n == 7)
    assert n == 7 and toy.calls[:6] == [(0, 2), (1, 2), (2, 2), (3, 2), (4, 2), (5, 1)]
    assert sched.position_lr(0, 2.0) == pytest.approx(2 * 1.6e-4)
    assert sched.position_lr(30, 1.0) == pytest.approx(1.6e-6)


class NaNAfter(ToyTarget):
    def step(self, p, it, downscale, sh_degree):
        if it == 3:
            with torch.no_grad():
                p["means"][5, 0] = float("nan")
        return super().step(p, it, downscale, sh_degree)


def test_non_finite_values_are_reported_with_the_step_and_the_objectives_where():
    with pytest.raises(NonFiniteError, match=r"toy run: training step 4 \(the toy view\): .*means"):
        _run(NaNAfter(look_at_camera(48, 36)), 20, context="toy run: ")
