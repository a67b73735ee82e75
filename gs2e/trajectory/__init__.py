"""gs2e.trajectory stage: smooth, densify and time virtual camera trajectories.

Public API::

    from gs2e.trajectory import Trajectory, load_trajectory, generate
    tr = load_trajectory("results/<scene>/trajectories/base_medium.npz")
    c2w = tr.pose_at(t_us)          # (Q, 4, 4) camera-to-world at any times in [0, duration]

Pure functions live in ``curve`` (smoothing, metric, curves, arc length),
``velocity`` (v(t) parsing, speed lists, reparameterisation) and ``trajectory``
(builders, presets, the Trajectory object); ``stage.generate`` runs the whole
stage on a scene; ``io`` writes and reads the files; ``cli`` is ``gs2e trajectory``.
"""

from gs2e.trajectory.io import load_trajectory, read_index
from gs2e.trajectory.stage import generate
from gs2e.trajectory.trajectory import Trajectory

__all__ = ["Trajectory", "load_trajectory", "read_index", "generate"]
