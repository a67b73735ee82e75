"""The ``dataset`` config section, typed: the quality gates of :mod:`gs2e.dataset.gates`.

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class DatasetSettings(Section):
    """The validated ``dataset`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "dataset"

    min_registered_fraction: float | None
    min_test_psnr_db: float | None
    min_events_per_pixel: float | None
