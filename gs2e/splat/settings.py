"""The ``splat`` config section, typed: the settings of training (:func:`gs2e.splat.train.train`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class SplatSettings(Section):
    """The validated ``splat`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "splat"

    model_source: str
    ply_path: str | None
    backend: str
    window: str
    compute_dtype: str
    max_iterations: int
    min_iterations: int
    eval_every: int
    plateau_patience: int
    plateau_min_delta_db: float
    test_every: int
    sh_degree: str | int
    sh_thresholds: list
    sh_increase_every: int
    max_side: int | None | str
    resolution_schedule: list
    budget: str | int
    budget_growth: float
    budget_min_gain_db: float
    budget_per_edge_pixel: float
    budget_min: int
    budget_max: int
    densify_from: int
    densify_until: int
    densify_every: int
    densify_grad_threshold: float
    percent_dense: float
    prune_min_opacity: float
    opacity_reset_every: int
    lr_position_init: float
    lr_position_final: float
    lr_sh_dc: float
    lr_sh_rest: float
    lr_opacity: float
    lr_scaling: float
    lr_rotation: float
    lambda_ssim: float
    init_opacity: float
    min_points: int
    background: list
    checkpoint_every: int
