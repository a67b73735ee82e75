"""gs2e.events: event-camera simulation from frame sequences.

Models (streaming, seeded, numba-compiled): :class:`VoltmeterModel`
(DVS-Voltmeter drift-diffusion) and :class:`IdealModel` (ESIM-style). Frame
sources yield ``(t_us int, float32 (H, W) linear luminance in [0, 1])``.
Outputs: DSEC-layout HDF5 (:class:`H5EventWriter`), text, npz; event frames,
voxel grids, preview video; statistics. See ``gs2e events --help``.

The package imports nothing (numba is loaded by the commands that simulate);
import from the modules: :mod:`gs2e.events.models`, :mod:`gs2e.events.presets`,
:mod:`gs2e.events.stats`.
"""
