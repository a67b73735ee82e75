"""One thread policy for every stage: how many CPUs this process may use, and
one call that sets torch, numba and child processes to a thread count.

A job sees every CPU of the node in ``os.cpu_count()``, but Slurm, taskset and
containers restrict it: by CPU affinity (cpusets; ``os.sched_getaffinity``) or
by a CPU-time quota (cgroup v2 ``cpu.max``, v1 ``cpu.cfs_quota_us``). More
threads than that only contend (numba and OpenMP spin and wait on each other).
``-1`` / ``None`` therefore mean "the CPUs this process may use", never more,
and an explicit count is capped the same way.
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path

# Read by OpenMP / BLAS runtimes when they load: child processes, and torch if
# this process imports it after set_threads (a loaded torch is set by call).
# NUMBA_NUM_THREADS is left alone: numba re-reads it and refuses a change once
# its thread pool runs.
CHILD_THREAD_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def _cgroup_mounts(mountinfo: Path) -> list[tuple[str, str, str, set[str]]]:
    """(fs type, root inside the hierarchy, mount point, super options) of the cgroup mounts."""
    out = []
    try:
        lines = mountinfo.read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        pre, _, post = line.partition(" - ")
        fields, tail = pre.split(), post.split()
        if len(fields) >= 5 and len(tail) >= 3 and tail[0] in ("cgroup", "cgroup2"):
            out.append((tail[0], fields[3], fields[4], set(tail[2].split(","))))
    return out


def _quota_cpus(fs: str, folder: Path) -> float | None:
    """The quota (CPUs) set in one cgroup folder, None if unlimited or unreadable."""
    try:
        if fs == "cgroup2":
            quota, period = (folder / "cpu.max").read_text().split()[:2]
            return None if quota == "max" else int(quota) / int(period)
        quota = int((folder / "cpu.cfs_quota_us").read_text())
        period = int((folder / "cpu.cfs_period_us").read_text())
        return quota / period if quota > 0 and period > 0 else None
    except (OSError, ValueError):
        return None


def cgroup_cpu_quota(proc_self: str | Path = "/proc/self") -> float | None:
    """CPU-time quota of this process's cgroup in CPUs (e.g. 1.5), None if unlimited.

    Follows ``<proc_self>/cgroup`` into the mounted hierarchies listed in
    ``<proc_self>/mountinfo`` (v2 ``cpu.max``; v1 ``cpu.cfs_quota_us`` /
    ``cpu.cfs_period_us``) and takes the smallest quota of the process's cgroup
    and its ancestors up to the mount point (a parent's limit binds the child).
    """
    proc_self = Path(proc_self)
    try:
        entries = [ln.split(":", 2) for ln in (proc_self / "cgroup").read_text().splitlines()]
    except OSError:
        return None
    limits = []
    for fs, root, mount, opts in _cgroup_mounts(proc_self / "mountinfo"):
        for entry in entries:
            if len(entry) != 3:
                continue
            _, controllers, path = entry
            if fs == "cgroup2":
                if controllers:
                    continue  # v1 hierarchy lines ("N:cpu,cpuacct:/path")
            elif "cpu" not in opts or "cpu" not in controllers.split(","):
                continue
            rel = os.path.relpath(path, root) if path.startswith(root) else None
            if rel is None or rel.startswith(".."):
                continue  # this mount does not show the process's cgroup
            folder = Path(mount) / rel
            while True:
                q = _quota_cpus(fs, folder)
                if q is not None:
                    limits.append(q)
                if folder == Path(mount) or folder.parent == folder:
                    break
                folder = folder.parent
    return min(limits) if limits else None


def available_cpus() -> int:
    """CPUs this process may use: its affinity mask, capped by a cgroup CPU
    quota (rounded up: a 1.5-CPU quota still runs 2 threads usefully)."""
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        n = os.cpu_count() or 1
    quota = cgroup_cpu_quota()
    if quota is not None:
        n = min(n, math.ceil(quota))
    return max(1, n)


def resolve_threads(threads: int | None) -> int:
    """Thread count for a request: None or <= 0 -> :func:`available_cpus`;
    a positive count is capped at it."""
    n = available_cpus()
    return n if threads is None or threads <= 0 else min(int(threads), n)


def pick_threads(cli: int | None, config: int | None = None) -> int | None:
    """The request that wins: an explicit ``--threads`` over the config value."""
    return config if cli is None else cli


def set_threads(threads: int | None) -> int:
    """Use ``threads`` (see :func:`resolve_threads`) in numba, torch and the
    OpenMP/BLAS environment; returns the count set.

    torch is not imported for this (it costs seconds, and the event stage on
    frames does not need it): a loaded torch is set by call, a torch loaded
    later reads ``OMP_NUM_THREADS``.
    """
    import numba

    n = resolve_threads(threads)
    for var in CHILD_THREAD_ENV:
        os.environ[var] = str(n)
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    if "torch" in sys.modules:
        sys.modules["torch"].set_num_threads(n)
    return n
