"""Adaptive temporal sampling of the event signal.

Events are triggered by log-intensity changes of about one contrast threshold
Theta. Sampling the rendered signal at a fixed high rate (the paper's 2400
fps) wastes renders where the image barely changes and can still be too coarse
where it changes fast. Here the step adapts so that the largest per-pixel
change of log intensity between consecutive samples stays below ``bound`` (a
fraction of Theta): a step that overshoots is rejected and retried shorter,
a quiet step lets the next one grow.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np


@dataclass
class SamplerStats:
    rendered: int = 0   # frames rendered, rejected ones included
    accepted: int = 0   # frames yielded
    rejected: int = 0
    max_change: float = 0.0  # largest accepted per-pixel log change
    forced: int = 0     # steps accepted at dt_min although above the bound
    min_step_us: int = 0
    max_step_us: int = 0


def max_log_change(log_a: np.ndarray, log_b: np.ndarray) -> float:
    return float(np.max(np.abs(log_b - log_a))) if log_a.size else 0.0


def adaptive_samples(render_log: Callable[[int], np.ndarray], t0_us: int, t1_us: int, bound: float,
                     dt_min_us: int, dt_max_us: int, dt_init_us: int | None = None,
                     stats: SamplerStats | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (t_us, log frame) from t0_us to t1_us (both included) such that
    consecutive log frames differ by at most ``bound`` per pixel, unless the
    step is already ``dt_min_us`` (then the step is taken and counted as forced).

    ``render_log(t_us)`` returns the log-intensity frame at an integer time.
    Steps are integers in [dt_min_us, dt_max_us]; growth is at most 2x per
    step. Memory: two frames.
    """
    if not (t1_us >= t0_us and 1 <= dt_min_us <= dt_max_us and bound > 0):
        raise ValueError(f"bad sampler arguments t0={t0_us} t1={t1_us} dt=[{dt_min_us},{dt_max_us}] bound={bound}")
    st = stats if stats is not None else SamplerStats()
    t = int(t0_us)
    cur = render_log(t)
    st.rendered += 1
    st.accepted += 1
    yield t, cur
    dt = int(dt_init_us or dt_min_us)
    while t < t1_us:
        dt = int(min(max(dt, dt_min_us), dt_max_us, t1_us - t))
        nxt = render_log(t + dt)
        st.rendered += 1
        change = max_log_change(cur, nxt)
        if change > bound and dt > dt_min_us:
            st.rejected += 1
            # shrink towards the step that would just meet the bound (locally linear signal)
            dt = max(dt_min_us, int(dt * max(0.2, 0.9 * bound / change)))
            continue
        if change > bound:
            st.forced += 1
        t += dt
        cur = nxt
        st.accepted += 1
        st.max_change = max(st.max_change, change) if change <= bound else st.max_change
        st.min_step_us = dt if st.min_step_us == 0 else min(st.min_step_us, dt)
        st.max_step_us = max(st.max_step_us, dt)
        yield t, cur
        grow = 2.0 if change <= 0 else min(2.0, 0.9 * bound / change)
        dt = max(dt_min_us, int(dt * max(1.0, grow)))
