"""gs2e.events: event-camera simulation from frame sequences.

Models (streaming, seeded, numba-compiled): :class:`VoltmeterModel`
(DVS-Voltmeter drift-diffusion) and :class:`IdealModel` (ESIM-style). Frame
sources yield ``(t_us int, float32 (H, W) linear luminance in [0, 1])``.
Outputs: DSEC-layout HDF5 (:class:`H5EventWriter`), text, npz; event frames,
voxel grids, preview video; statistics. See ``gs2e events --help``.
"""

from gs2e.events.models import Events, IdealModel, VoltmeterModel, make_model
from gs2e.events.presets import PRESETS, Preset, effective_threshold, get_preset
from gs2e.events.stats import StatsAccumulator, calibrate_noise, event_stats

__all__ = ["Events", "IdealModel", "VoltmeterModel", "make_model", "PRESETS", "Preset",
           "effective_threshold", "get_preset", "event_stats", "calibrate_noise",
           "StatsAccumulator"]
