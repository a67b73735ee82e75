"""The ``export`` config section, typed: the settings of the export stage (:mod:`gs2e.export.run`).

Each field is a key of the section; its meaning, type and default are the
schema's (``gs2e/schemas/config.schema.yaml``, listed in config/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from gs2e.common.settings import Section


@dataclass(frozen=True)
class ExportSettings(Section):
    """The validated ``export`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "export"

    formats: list
    trajectories: list | None
    metres_per_unit: float
    flow_png: bool
    flow_per_event: bool
    imu_rate_hz: float
    imu_preset: str
    imu_gravity: str | list
    imu_T_cam_imu: list | None
    imu_time_offset_us: int
    rosbag_topic_prefix: str
    rosbag_event_window_us: int
    rosbag_image: str
    rosbag_image_encoding: str
    rosbag_pose_rate_hz: float
    rosbag_compression: str
    eventnerf_fit: str
    eventnerf_holdout_every: int
    eventnerf_winsize: int | None
    e2nerf_loader: str
    evdeblurnerf_llffhold: int
    evdeblurnerf_pose_rate_hz: float
    event3dgs_intensity: str
    inceventgs_jpeg_quality: int
