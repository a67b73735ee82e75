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

__all__ = ["Trajectory", "load_trajectory", "read_index", "generate", "fixed_times_us"]

_LAZY = {"Trajectory": "gs2e.trajectory.trajectory", "load_trajectory": "gs2e.trajectory.io",
         "read_index": "gs2e.trajectory.io", "generate": "gs2e.trajectory.stage",
         "fixed_times_us": "gs2e.trajectory.trajectory"}


def __getattr__(name: str):
    # lazy: `gs2e --help` imports gs2e.trajectory.cli and must not load numba/scipy
    if name in _LAZY:
        import importlib
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'gs2e.trajectory' has no attribute {name!r}")
