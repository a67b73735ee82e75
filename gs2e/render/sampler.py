"""Adaptive temporal sampling of the event signal.

Events are triggered by log-intensity changes of about one contrast threshold
Theta. Sampling the rendered signal at a fixed high rate (the paper's 2400
fps) wastes renders where the image barely changes and can still be too coarse
where it changes fast. Here the step adapts so that the largest per-pixel
change of log intensity between consecutive samples stays below ``bound`` (a
fraction of Theta): a step that overshoots is rejected and retried shorter.
After an accepted step the next one is predicted from it (change assumed
proportional to the step, aiming at 0.9 x bound): it grows by at most 2x
when the image is quiet and shrinks by at most 2x before the change reaches
the bound, so that few trial renders are wasted on rejections.

``outlier_fraction`` > 0 sets the largest changes of that fraction of the
pixels aside: a handful of near-black pixels (where log(L + eps) is steep)
or silhouette pixels that jump would otherwise hold the step at its minimum
for the whole image (measured in benchmarks/bench_temporal_sampling.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterator

import numpy as np


@dataclass
class SamplerStats:
    rendered: int = 0   # frames rendered, rejected ones included
    accepted: int = 0   # frames yielded
    rejected: int = 0   # trial frames over the bound (kept: a later step may end there)
    reused: int = 0     # rejected trials accepted later (no render wasted)
    max_change: float = 0.0  # largest accepted per-pixel log change
    forced: int = 0     # steps accepted at dt_min although above the bound
    min_step_us: int = 0
    max_step_us: int = 0


def max_log_change(log_a: np.ndarray, log_b: np.ndarray, outlier_fraction: float = 0.0) -> float:
    """Largest per-pixel |log_b - log_a|; with ``outlier_fraction`` f > 0 the
    largest once the floor(f N) largest of the N pixels are set aside."""
    if not log_a.size:
        return 0.0
    d = np.abs(log_b - log_a).ravel()
    k = int(outlier_fraction * d.size)
    if k <= 0:
        return float(d.max())
    k = min(k, d.size - 1)
    return float(np.partition(d, d.size - 1 - k)[d.size - 1 - k])


def adaptive_samples(render_log: Callable[[int], np.ndarray], t0_us: int, t1_us: int, bound: float,
                     dt_min_us: int, dt_max_us: int, dt_init_us: int | None = None,
                     stats: SamplerStats | None = None,
                     outlier_fraction: float = 0.0) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (t_us, log frame) from t0_us to t1_us (both included) such that
    consecutive log frames differ by at most ``bound`` per pixel, unless the
    step is already ``dt_min_us`` (then the step is taken and counted as forced);
    with ``outlier_fraction`` f > 0, all pixels but the floor(f N) that change
    most (see :func:`max_log_change`).

    ``render_log(t_us)`` returns the log-intensity frame at an integer time.
    Steps are integers in [dt_min_us, dt_max_us] (the last one may be
    shorter); growth is at most 2x per step. Rejected trial frames are kept
    and, once a shorter step has been accepted, tried as the next sample
    without rendering: no time is rendered twice. Memory: two frames plus
    the rejected trials ahead of the current time (a few).
    """
    if not (t1_us >= t0_us and 1 <= dt_min_us <= dt_max_us and bound > 0 and 0 <= outlier_fraction < 1):
        raise ValueError(f"bad sampler arguments t0={t0_us} t1={t1_us} dt=[{dt_min_us},{dt_max_us}] "
                         f"bound={bound} outlier_fraction={outlier_fraction}")
    st = stats if stats is not None else SamplerStats()
    t = int(t0_us)
    cur = render_log(t)
    st.rendered += 1
    st.accepted += 1
    yield t, cur
    dt = int(dt_init_us or dt_min_us)
    pending: dict[int, np.ndarray] = {}  # rejected trials ahead of t: later steps may end there
    accepted = True
    while t < t1_us:
        nearest = min(pending) if pending else None
        if accepted and nearest is not None and nearest - t >= dt_min_us:
            t_new, nxt, reused = nearest, pending[nearest], True  # costs no render
        else:
            dt = int(min(max(dt, dt_min_us), dt_max_us, t1_us - t))
            t_new = t + dt
            reused = t_new in pending
            nxt = pending[t_new] if reused else render_log(t_new)
            st.rendered += int(not reused)
        accepted = False
        step = t_new - t
        change = max_log_change(cur, nxt, outlier_fraction)
        if change > bound and step > dt_min_us:
            if not reused:
                st.rejected += 1
                pending[t_new] = nxt
            # shrink towards the step that would just meet the bound (locally linear signal)
            dt = max(dt_min_us, int(step * max(0.2, 0.9 * bound / change)))
            continue
        if change > bound:
            st.forced += 1
        st.reused += int(reused)
        t, cur, accepted = t_new, nxt, True
        for k in [k for k in pending if k <= t]:
            del pending[k]
        st.accepted += 1
        st.max_change = max(st.max_change, change) if change <= bound else st.max_change
        st.min_step_us = step if st.min_step_us == 0 else min(st.min_step_us, step)
        st.max_step_us = max(st.max_step_us, step)
        yield t, cur
        # predict the next step from this one; shrinking ahead of the bound
        # avoids the wasted render of a rejected trial
        grow = 2.0 if change <= 0 else min(2.0, max(0.5, 0.9 * bound / change))
        dt = max(dt_min_us, int(step * grow))
