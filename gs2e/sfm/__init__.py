"""Structure-from-motion with COLMAP (pycolmap): cameras and sparse points.

``run_sfm`` takes a scene in the internal layout (gs2e.io.scene) and writes an
undistorted (PINHOLE) scene in the same layout plus the COLMAP model in
``sparse/0`` (the layout 3DGS implementations read), with statistics.
"""

from gs2e.sfm.align import alignment_errors
from gs2e.sfm.colmap_sfm import choose_matcher, run_sfm

__all__ = ["run_sfm", "choose_matcher", "alignment_errors"]
