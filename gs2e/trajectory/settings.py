"""The ``trajectory`` config section, typed: the settings of
the trajectory stage (:mod:`gs2e.trajectory.stage`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class TrajectorySettings(Section):
    """The validated ``trajectory`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "trajectory"

    view_order: str
    smooth_half_width: int
    gamma: float
    alpha: float
    beta: float
    normalize_translation: bool
    interpolation: str
    velocity: str
    speed_list: list | None
    speed_list_tau: float
    fps_base: float
    presets: dict
    speed_presets: list
    min_duration_s: float | None
    mini_groups: int
    mini_keyframes: int
    mini_frames: int
    mini_window: float
    mini_min_view: float
    mini_degrees: list
    mini_bspline_probability: float
    mini_preset: str
    seed: int
    plot: bool
