"""The ``metrics`` config section, typed: the settings of the report (:mod:`gs2e.report.build`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class MetricsSettings(Section):
    """The validated ``metrics`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "metrics"

    real_events: str | None
    preview_window_ms: float
    thumbnail_max_side_px: int
    max_scene_sections: int
