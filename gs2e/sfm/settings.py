"""The ``sfm`` config section, typed: the settings of
structure from motion (:func:`gs2e.sfm.colmap_sfm.run_sfm`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class SfmSettings(Section):
    """The validated ``sfm`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "sfm"

    reuse_poses: bool
    matcher: str
    exhaustive_max_views: int
    sequential_overlap: int
    sequential_loop_detection: bool
    max_num_features: int
    max_image_size: int | str | None
    sift_first_octave: str | int
    extractor: str
    descriptor_matcher: str
    bundle_adjustment: str
    camera_model: str
    single_camera: bool
    min_registered_fraction: float
    num_threads: int
    deterministic: bool
    gpu: bool
