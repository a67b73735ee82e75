"""gs2e: sparse multi-view photos of static scenes -> event-camera datasets.

One subpackage per pipeline stage (io, sfm, splat, trajectory, render, events,
metrics); each is a set of pure functions on arrays plus a thin I/O edge. The
``gs2e`` command (``gs2e.cli``) exposes one subcommand per stage.
"""

import os

# On a shared 2-core machine, OpenMP threads that spin-wait between parallel
# regions (torch's and numba's runtimes both do by default) burn half the CPU
# time of a render (measured: 0.74 -> 0.35 CPU-s per 256x256/50k step). Only
# effective before torch/numba load their OpenMP runtime, hence here.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

__version__ = "0.1.0"
