"""gs2e: sparse multi-view photos of static scenes -> event-camera datasets.

One subpackage per pipeline stage (io, sfm, splat, trajectory, render, events,
metrics); each is a set of pure functions on arrays plus a thin I/O edge. The
``gs2e`` command (``gs2e.cli``) exposes one subcommand per stage.
"""

__version__ = "0.1.0"
