"""Structure-from-motion with COLMAP (pycolmap): cameras and sparse points.

``run_sfm`` takes a scene in the internal layout (gs2e.io.scene) and writes an
undistorted (PINHOLE) scene in the same layout plus the COLMAP model in
``sparse/0`` (the layout 3DGS implementations read), with statistics.

The package imports nothing: ``gs2e`` declares every stage's arguments on
start-up, and importing scipy and pandas here cost every command ~0.35 s.
Import from the modules: :mod:`gs2e.sfm.colmap_sfm` (``run_sfm``,
``choose_matcher``), :mod:`gs2e.sfm.align` (``alignment_errors``).
"""
