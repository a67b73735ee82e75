"""The export formats, registered in one place.

Everything that names a format derives from :data:`FORMATS`: ``gs2e export
--format`` choices, :func:`gs2e.export.run.export_trajectory` and the
benchmark of the exports; the schema's ``export.formats`` enum is held equal
to it by ``tests/test_export_formats.py``. Light on purpose (no numerical
imports): the CLI's argument parser reads it; a format's module is imported
when it runs.

Adding a format: write ``export_mine(src, out, cfg)`` (src a
:class:`gs2e.export.source.TrajectorySource`, out a
:class:`gs2e.export.common.ExportOut`, cfg the ``export`` settings,
:class:`gs2e.export.settings.ExportSettings`; with
``seeded``, also ``seed=``), then ``register(Format("mine",
"mypkg.mine:export_mine"))``; for the workflow, add the name to the schema's
``export.formats`` enum.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from gs2e.common.registry import PluginRegistry, add, resolve


@dataclass(frozen=True)
class Format:
    """One export format: its name, its function (``module:function``), whether
    it draws random numbers (then it gets the job's ``seed=``) and a line for
    ``gs2e export --help``."""

    name: str
    run: str
    seeded: bool = False
    help: str = ""

    def runner(self) -> Callable:
        return resolve(self.run)


FORMATS: dict[str, Format] = PluginRegistry("gs2e.export_formats")


def register(fmt: Format) -> Format:
    """Add ``fmt`` (its name: lower-case letters and digits, the workflow's
    ``{fmt}`` wildcard) to the registry."""
    return add(FORMATS, fmt.name, fmt, "export format", r"[a-z][a-z0-9]*")


for _f in (
        Format("eventnerf", "gs2e.export.eventnerf:export_eventnerf", help="EventNeRF"),
        Format("e2nerf", "gs2e.export.e2nerf:export_e2nerf", help="E2NeRF / E2GS"),
        Format("evdeblurnerf", "gs2e.export.evdeblurnerf:export_evdeblurnerf", help="EvDeblurNeRF"),
        Format("inceventgs", "gs2e.export.inceventgs:export_inceventgs", help="IncEventGS"),
        Format("event3dgs", "gs2e.export.event3dgs:export_event3dgs", help="Event-3DGS"),
        Format("flow", "gs2e.export.flow:export_flow", help="optical flow and depth ground truth"),
        Format("imu", "gs2e.export.imu:export_imu", seeded=True, help="IMU with Kalibr files"),
        Format("rosbag", "gs2e.export.rosbag:export_rosbag", seeded=True,
               help="ROS 1 bag, Event Camera Dataset topics"),
        Format("rosbag2", "gs2e.export.rosbag:export_rosbag2", seeded=True,
               help="ROS 2 bag (MCAP), the same topics")):
    register(_f)
FORMATS.plugins(register, lambda f: f.name)
