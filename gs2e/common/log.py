"""Logging: every stage logs what it ran and how long each step took."""

from __future__ import annotations

import contextlib
import logging
import sys
import time
from typing import Iterator

_FMT = "%(asctime)s %(levelname)s %(name)s: %(message)s"


def setup_logging(verbose: bool = False) -> None:
    """Log to stderr (Snakemake rules redirect stderr into the rule's log)."""
    logging.basicConfig(
        level=logging.DEBUG if verbose else logging.INFO,
        format=_FMT,
        datefmt="%H:%M:%S",
        stream=sys.stderr,
        force=True,
    )


def process_usage() -> tuple[float, float]:
    """This process's CPU seconds (user + system, all threads, plus the children it
    waited for) and peak resident memory in MB (the larger of its own and its
    largest child's), exact from the kernel (getrusage), unlike a sampler that
    misses what runs after its last sample."""
    import resource

    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime
    return cpu_s, max(me.ru_maxrss, kids.ru_maxrss) / 1024.0  # ru_maxrss: KiB on Linux


def get_logger(name: str) -> logging.Logger:
    return logging.getLogger(name)


@contextlib.contextmanager
def timed(step: str, logger: logging.Logger | None = None,
          timings: dict[str, float] | None = None) -> Iterator[None]:
    """Log the wall time of a step; store seconds in ``timings[step]`` if given."""
    log = logger or logging.getLogger("gs2e")
    t0 = time.perf_counter()
    log.info("%s ...", step)
    try:
        yield
    finally:
        dt = time.perf_counter() - t0
        if timings is not None:
            timings[step] = dt
        log.info("%s done in %.2f s", step, dt)
