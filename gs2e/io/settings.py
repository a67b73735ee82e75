"""The ``ingest`` config section, typed: the settings of
ingest (:func:`gs2e.io.ingest.ingest_scene`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class IngestSettings(Section):
    """The validated ``ingest`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "ingest"

    max_views: int | None
    max_side: int | None | str
    downscale: int
    images_subdir: str | None
    allow_mixed_resolutions: bool
