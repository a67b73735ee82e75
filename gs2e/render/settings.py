"""The ``render`` config section, typed: the settings of
the render stage (:func:`gs2e.render.dataset.render_dataset`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class RenderSettings(Section):
    """The validated ``render`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "render"

    trajectories: list
    fps: float
    exposure_us: float
    write_blur: bool
    write_depth: bool
    blur_max_step_px: float
    blur_max_subframes: int
    blur_tolerance_db: float | None
    scale: float
    background: list
    backend: str
    order_step_px: float
    camera: dict
    min_coverage: float
