"""The ``demo`` config section, typed: the settings of
the demo scene (:func:`gs2e.demo.io.generate_demo_scene`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class DemoSettings(Section):
    """The validated ``demo`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "demo"

    n_views: int
    width: int
    height: int
    fov_deg: float
    orbit_radius: float
    orbit_elevation_deg: float
    elevation_wobble_deg: float
    supersample: int
    n_points: int
    seed: int
