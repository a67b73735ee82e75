"""Shared helpers: atomic file output, logging with timings, progress bars."""

from gs2e.common.atomic import atomic_dir, atomic_file, write_json_atomic
from gs2e.common.errors import GS2EError, InputError, ConfigError
from gs2e.common.log import get_logger, setup_logging, timed
from gs2e.common.progress import progress

__all__ = [
    "atomic_dir",
    "atomic_file",
    "write_json_atomic",
    "GS2EError",
    "InputError",
    "ConfigError",
    "get_logger",
    "setup_logging",
    "timed",
    "progress",
]
