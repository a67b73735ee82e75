"""Temporal sampling of a rendered event signal: fixed, adaptive, per tile.

The event models consume the linear luminance L of each pixel at a sequence
of sample times (:class:`gs2e.events.models.TileBatch`); between two samples
the ideal model takes log(L + eps) as linear in time and DVS-Voltmeter takes
L's drift as constant. How densely to sample is the event stage's choice
(config section ``events.sampling``):

``fixed``
    every pixel at ``fixed_fps`` (the paper: 2400 fps).
``adaptive``
    one clock for the whole image: steps such that the largest per-pixel
    change of G = log(L + log_eps) between consecutive samples stays below the
    bound, over all pixels but the ``outlier_fraction`` that change most.
``motion``
    one clock for the whole image, bounded by the scene's projected motion:
    steps such that no drawn Gaussian's centre moves more than
    ``max_motion_px`` between consecutive samples, in units of its own
    projected scale (:func:`gs2e.splat.forward.image_motion_px`), measured
    on the trajectory's continuous pose. Costs one projection per step, no
    trial renders; blind to what motion does not drive (view-dependent colour).
``curve``
    one clock for the whole image, bounded by the measured error of the curve
    the event models see between renders (the cubic through them with
    ``substeps`` > 1, else the line): each new render's residual against the
    curve through the earlier ones estimates the signal's third (second)
    derivative, and a step whose estimated error exceeds the bound is
    rendered again shorter (:func:`curve_error`). Long steps where the signal
    is smooth in time, short ones at a disocclusion, a Gaussian near the
    camera or a depth-order cross-fade; with ``max_motion_px`` set, steps are
    also capped by the image motion. Meant for models continuous in time
    (``splat.window: smooth``, issue 67).
``tile``
    one clock per 16 x 16 tile (the rasterizer's tiles). Guarantee, per pixel,
    between consecutive samples of its tile:
    ``|G(t_{i+1}) - G(t_i)| <= bound``, unless the step is already
    ``dt_min_us`` (then it is taken and counted as forced); and, with
    ``max_motion_px`` set, no Gaussian that can reach the tile moves its
    projected centre by more than that many pixels. A tile is rendered only
    when its own change is predicted to reach the bound, so flat, dark or
    still regions cost almost nothing while edges are sampled as finely as
    they need; a tile that no Gaussian can reach, or whose Gaussians do not
    move, keeps its value exactly and is sampled once per window (below).

Per-tile clocks are dyadic: steps are ``dt_min_us * 2^k`` and a tile's last
sample time (relative to the start) is a multiple of its step, so tiles
rendered at the same time share one projection of the Gaussians that can
reach them (:class:`gs2e.splat.forward.ForwardRenderer`). A step that
overshoots the bound is rejected and halved (or shortened to the predicted
step); the rejected render is kept and used when the tile reaches that
time, so no time of a tile is rendered twice. After an accepted step the next
one is predicted from its rate of change (aiming at 0.9 x bound, growth at most
2x per step).

Which Gaussians can reach a tile is computed per time window (a few poses of
the trajectory; :meth:`ForwardRenderer.candidates`), with windows short enough
that projected centres move at most ``window_motion_px`` between the poses.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Callable, Iterator

import numpy as np
from numba import njit, prange

from gs2e.common.color import srgb_decode, srgb_decode_slope
from gs2e.common.errors import ConfigError
from gs2e.events._kernels import tile_box
from gs2e.events.models import TILE, TileBatch

MODES = ("fixed", "adaptive", "motion", "curve", "tile")


@dataclass
class SamplerStats:
    """What sampling cost: renders and rendered pixel values."""

    renders: int = 0          # render calls (whole images or sets of tiles)
    tiles_rendered: int = 0   # tile renders (rejected trials included)
    pixel_samples: int = 0    # rendered pixel values (tile renders x TILE^2, or H x W per frame)
    accepted: int = 0         # samples used (per tile in tile mode, frames otherwise)
    rejected: int = 0         # trial samples over the bound (kept for later use)
    reused: int = 0           # rejected trials used later without rendering
    forced: int = 0           # steps taken at dt_min although over the bound
    max_change: float = 0.0   # largest accepted change of G (unforced)
    min_step_us: int = 0
    max_step_us: int = 0
    windows: int = 0          # candidate windows built (tile mode)
    tangents: int = 0         # tangent passes (events.sampling.slopes: tangent), not renders
    # fixed mode, rendered: image motion (px, image_motion_px) over one step at
    # evenly spread times (None where not measured)
    step_motion_px_p50: float | None = None
    step_motion_px_max: float | None = None

    def step(self, step_us: int) -> None:
        self.min_step_us = step_us if self.min_step_us == 0 else min(self.min_step_us, step_us)
        self.max_step_us = max(self.max_step_us, step_us)


# ---------------------------------------------------------------- kernels
@njit(cache=True)
def _srgb_lum(r, g, b):
    """Rec. 709 luminance of sRGB-encoded values (clamped to [0, 1]) in linear light."""
    acc = 0.0
    for c, w in ((r, 0.2126), (g, 0.7152), (b, 0.0722)):
        acc += w * srgb_decode(min(max(float(c), 0.0), 1.0))
    return acc


@njit(cache=True, parallel=True)
def image_luminance(image, out):
    """(H, W) linear luminance of an (H, W, 3) sRGB image."""
    for y in prange(image.shape[0]):
        for x in range(image.shape[1]):
            out[y, x] = _srgb_lum(image[y, x, 0], image[y, x, 1], image[y, x, 2])


@njit(cache=True, parallel=True)
def image_luminance_rate(image, rate, channels, lum, dlum):
    """Linear value lum (H, W) of an (H, W, 3) sRGB ``image`` and its time
    derivative dlum from the image's ``rate`` (H, W, 3; per us): Rec. 709
    luminance, or with ``channels`` (2, 2) int64 (:func:`cfa_channels`) each
    pixel's own channel (a (0, 0) array: luminance). A value clamped to
    [0, 1] before decoding has no rate."""
    cfa = channels.shape[0] == 2
    for y in prange(image.shape[0]):
        for x in range(image.shape[1]):
            acc, dacc = 0.0, 0.0
            for c, w in ((0, 0.2126), (1, 0.7152), (2, 0.0722)):
                if cfa:
                    if c != channels[y % 2, x % 2]:
                        continue
                    w = 1.0
                v = float(image[y, x, c])
                vc = min(max(v, 0.0), 1.0)
                acc += w * srgb_decode(vc)
                if vc == v:
                    dacc += w * srgb_decode_slope(v) * rate[y, x, c]
            lum[y, x] = acc
            dlum[y, x] = dacc


# colour filter arrays: the channel (0 R, 1 G, 2 B) over pixel (y % 2, x % 2)
CFA_CHANNELS = {"RGGB": ((0, 1), (1, 2)), "BGGR": ((2, 1), (1, 0)),
                "GRBG": ((1, 0), (2, 1)), "GBRG": ((1, 2), (0, 1))}


def cfa_channels(pattern: str) -> np.ndarray:
    """(2, 2) int64 channel of each pixel of a 2x2 CFA tile (ConfigError if unknown)."""
    if pattern not in CFA_CHANNELS:
        raise ConfigError(f"events.cfa: unknown pattern '{pattern}' (choose from {', '.join(CFA_CHANNELS)})")
    return np.array(CFA_CHANNELS[pattern], np.int64)


@njit(cache=True, parallel=True)
def image_cfa(image, channels, out):
    """(H, W) linear value of each pixel's own channel of an (H, W, 3) sRGB
    image, ``channels`` (2, 2) its CFA tile (:func:`cfa_channels`): what a
    pixel under a colour filter sees, instead of the luminance."""
    for y in prange(image.shape[0]):
        for x in range(image.shape[1]):
            c = channels[y % 2, x % 2]
            out[y, x] = srgb_decode(min(max(float(image[y, x, c]), 0.0), 1.0))


@njit(cache=True, parallel=True)
def tile_samples(image, tiles, H, W, log_eps, g_last, lum, g_new, change):
    """For tiles ``tiles`` of an sRGB image: linear luminance lum (n, T, T),
    G = log(lum + log_eps) g_new (n, T, T) and the largest |G - g_last| over
    the tile's pixels (change (n,)); pixels beyond the image get 0 / G of 0."""
    T = lum.shape[1]
    tiles_x = (W + T - 1) // T
    for s in prange(tiles.shape[0]):
        ty = tiles[s] // tiles_x
        tx = tiles[s] - ty * tiles_x
        mx = 0.0
        for i in range(T):
            y = ty * T + i
            for j in range(T):
                x = tx * T + j
                if y < H and x < W:
                    v = _srgb_lum(image[y, x, 0], image[y, x, 1], image[y, x, 2])
                    gv = math.log(v + log_eps)
                    mx = max(mx, abs(gv - g_last[y, x]))
                else:
                    v = 0.0
                    gv = math.log(log_eps)
                lum[s, i, j] = v
                g_new[s, i, j] = gv
        change[s] = mx


@njit(cache=True)
def _tile_change(g_tile, g_last, t, H, W):
    """Largest |G - g_last| over the pixels of tile t."""
    T = g_tile.shape[0]
    tiles_x = (W + T - 1) // T
    ty = t // tiles_x
    tx = t - ty * tiles_x
    mx = 0.0
    for i in range(T):
        y = ty * T + i
        if y >= H:
            break
        for j in range(T):
            x = tx * T + j
            if x >= W:
                break
            mx = max(mx, abs(g_tile[i, j] - g_last[y, x]))
    return mx


@njit(cache=True)
def _commit_tiles(g_new, idx, tiles, g_last):
    """g_last <- g_new[idx[i]] over the pixels of tile tiles[i] inside the image."""
    H, W = g_last.shape
    T = g_new.shape[1]
    tiles_x = (W + T - 1) // T
    for i in range(tiles.shape[0]):
        y0, y1, x0, x1 = tile_box(tiles[i], tiles_x, T, H, W)
        for y in range(y0, y1):
            for x in range(x0, x1):
                g_last[y, x] = g_new[idx[i], y - y0, x - x0]


@njit(cache=True)
def _next_level(old, step_us, change, rel_us, q, max_lvl, dt_max_us, bound, max_motion_px,
                speed_px_per_us):
    """Level of a tile's next step after an accepted step of ``step_us`` with
    change ``change``, at ``rel_us`` from the start (a multiple of q << level):
    aiming at 0.9 x bound, at most twice the step, at most one level up, at
    most ``dt_max_us``, and (``max_motion_px`` >= 0) at most that motion."""
    cap = min(2.0 * max(q << old, step_us), float(dt_max_us))
    if change > 0.0:
        cap = min(cap, 0.9 * bound / change * step_us)
    if max_motion_px >= 0.0 and speed_px_per_us > 0.0:
        cap = min(cap, max_motion_px / speed_px_per_us)
    new = int(math.floor(math.log2(max(1.0, cap / q))))
    new = max(0, min(new, max_lvl, old + 1))
    while new > 0 and rel_us % (q << new):
        new -= 1
    return new


@njit(cache=True)
def _next_levels(tiles, change, step_us, t_us, t0_us, t1_us, q, max_lvl, dt_max_us, bound,
                 max_motion_px, speed_px_per_us, lvl, t_next):
    """:meth:`TileSampler._next_time` for tiles accepted at ``t_us`` that hold
    no pending trial and are not static with zero change: sets lvl and t_next."""
    for i in range(tiles.shape[0]):
        k = tiles[i]
        if t_us >= t1_us:
            t_next[k] = t1_us
            continue
        lvl[k] = _next_level(lvl[k], step_us[i], change[i], t_us - t0_us, q, max_lvl, dt_max_us,
                             bound, max_motion_px, speed_px_per_us[k])
        t_next[k] = min(t_us + (q << lvl[k]), t1_us)


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


# curve_error: the largest interpolation error over a step of 1 as a multiple of
# the divided difference of that degree (cubic: Catmull-Rom's 0.0962 for g''' / 6;
# line: 1/8 |g''| = 1/4 of g'' / 2)
CURVE_ERROR_COEF = {3: 0.0962, 2: 0.25}


def curve_error(history, t_us: int, g: np.ndarray, degree: int,
                outlier_fraction: float = 0.0) -> float | None:
    """Estimated largest error of the curve between the last sample of
    ``history`` and a new sample (``t_us``, ``g``), over all pixels but the
    ``outlier_fraction`` worst (as :func:`max_log_change`), in the units of g:
    the measured curvature bound of mode ``curve``.

    ``history``: earlier accepted samples ((t_us, (H, W) log frame), oldest
    first). ``degree`` 3: the cubic through the renders (Catmull-Rom,
    :func:`gs2e.events.rendered.cubic_substeps`), whose error on a step h is
    at most 0.0962 h^3 |g'''| / 6 (the extremum of s (2s - 1)(s - 1) on
    [0, 1], the error of Catmull-Rom on g = t^3; uneven steps taken as even);
    degree 2: the line, at most h^2 |g''| / 8. The derivative is the divided
    difference of the new sample and the last ``degree`` of ``history``: the
    residual of their polynomial extrapolated to ``t_us``, over the product
    of the distances. Zero on a polynomial of degree - 1; a jump (a
    disocclusion, a Gaussian near the camera) shows as a large residual.
    None while ``history`` holds fewer than ``degree`` samples. Conservative
    for a cubic with exact slopes (``events.sampling.slopes: difference``),
    whose error is O(h^4). ValueError for another degree.
    """
    if degree not in CURVE_ERROR_COEF:
        raise ValueError(f"curve_error: degree must be 2 or 3, got {degree}")
    if len(history) < degree:
        return None
    pts = list(history)[-degree:]
    ts = [float(ti) for ti, _ in pts]
    t = float(t_us)
    pred = np.zeros(g.shape, np.float64)
    for i, (_, gi) in enumerate(pts):  # Lagrange's polynomial, extrapolated to t
        pred += math.prod((t - tj) / (ts[i] - tj) for j, tj in enumerate(ts) if j != i) * gi
    span = abs(math.prod(t - ti for ti in ts))
    h = t - ts[-1]
    return max_log_change(pred, g, outlier_fraction) / span * CURVE_ERROR_COEF[degree] * h ** degree


def adaptive_samples(render_log: Callable[[int], np.ndarray], t0_us: int, t1_us: int, bound: float,
                     dt_min_us: int, dt_max_us: int, dt_init_us: int | None = None,
                     stats: SamplerStats | None = None, outlier_fraction: float = 0.0,
                     first_log: np.ndarray | None = None, degree: int | None = None,
                     limit: Callable[[int, int], int] | None = None,
                     history: "deque | None" = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (t_us, log frame) from t0_us to t1_us (both included) such that
    consecutive log frames differ by at most ``bound`` per pixel, unless the
    step is already ``dt_min_us`` (then the step is taken and counted as forced);
    with ``outlier_fraction`` f > 0, all pixels but the floor(f N) that change
    most (see :func:`max_log_change`). One clock for the whole image.

    With ``degree`` (2 or 3: mode ``curve``) the bound is on the estimated
    error of the curve between samples (:func:`curve_error`) instead of the
    change, and steps scale by its ``degree``-th root; the first step is
    taken unchecked (nothing to estimate from) and the next ones with the
    line's estimate until ``degree`` samples exist. ``history``: a deque of
    accepted (t_us, log frame) that the estimate reads, carried from span to
    span by the caller (a last sample at t0 is then not rendered again); by
    default a new one.
    ``limit(t_us, step_us)``: the longest step from t_us, at most step_us,
    that another bound allows (mode ``curve``: the image motion).

    ``render_log(t_us)`` returns the log-intensity frame at an integer time.
    Steps are integers in [dt_min_us, dt_max_us] (the last one may be
    shorter); growth is at most 2x per step. Rejected trial frames are kept
    and, once a shorter step has been accepted, tried as the next sample
    without rendering: no time is rendered twice. Memory: two frames plus
    the rejected trials ahead of the current time (a few; with ``degree``,
    ``degree`` - 1 more). ``first_log``: the frame at t0 if the caller has it
    (not rendered again).
    """
    if not (t1_us >= t0_us and 1 <= dt_min_us <= dt_max_us and bound > 0 and 0 <= outlier_fraction < 1):
        raise ValueError(f"bad sampler arguments t0={t0_us} t1={t1_us} dt=[{dt_min_us},{dt_max_us}] "
                         f"bound={bound} outlier_fraction={outlier_fraction}")
    st = stats if stats is not None else SamplerStats()
    hist = history if history is not None else deque(maxlen=degree or 1)
    root = 1.0 / (degree or 1)
    t = int(t0_us)
    if hist and hist[-1][0] == t:
        cur = hist[-1][1]
    else:
        cur = render_log(t) if first_log is None else first_log
        hist.append((t, cur))
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
            if limit is not None:
                dt = max(min(dt_min_us, t1_us - t), int(limit(t, dt)))
            t_new = t + dt
            reused = t_new in pending
            nxt = pending[t_new] if reused else render_log(t_new)
        accepted = False
        step = t_new - t
        # a curve's error once enough samples exist (the line's after the first step)
        change = (max_log_change(cur, nxt, outlier_fraction) if degree is None
                  else curve_error(hist, t_new, nxt, min(degree, len(hist)), outlier_fraction)
                  if len(hist) >= 2 else None)
        if change is not None and change > bound and step > dt_min_us:
            if not reused:
                st.rejected += 1
                pending[t_new] = nxt
            # shrink towards the step that would just meet the bound (locally linear signal)
            dt = max(dt_min_us, int(step * max(0.2, 0.9 * (bound / change) ** root)))
            continue
        if change is not None and change > bound:
            st.forced += 1
        st.reused += int(reused)
        t, cur, accepted = t_new, nxt, True
        hist.append((t, cur))
        for k in [k for k in pending if k <= t]:
            del pending[k]
        st.accepted += 1
        if change is not None and change <= bound:
            st.max_change = max(st.max_change, change)
        st.step(step)
        yield t, cur
        # predict the next step from this one; shrinking ahead of the bound
        # avoids the wasted render of a rejected trial
        grow = (1.0 if change is None else 2.0 if not change  # unchecked steps do not grow
                else min(2.0, max(0.5, 0.9 * (bound / change) ** root)))
        dt = max(dt_min_us, int(step * grow))


def motion_times(project: Callable[[int], object], motion: Callable[[object, object], float],
                 t0_us: int, t1_us: int, max_motion_px: float, dt_min_us: int, dt_max_us: int,
                 dt_init_us: int | None = None,
                 stats: SamplerStats | None = None) -> Iterator[int]:
    """Yield sample times (us) from t0_us to t1_us (both included) such that
    the image motion between consecutive ones, ``motion(project(t_a),
    project(t_b))``, is at most ``max_motion_px``, unless the step is already
    ``dt_min_us`` (taken and counted as forced). Steps are integers in
    [dt_min_us, dt_max_us] (the last may be shorter), growth at most 2x per
    step, aiming at 0.9 x the bound; a trial over the bound is shortened to
    the step that would just meet it (motion locally linear in time). Costs
    projections only (``project`` is called once per trial)."""
    if not (t1_us >= t0_us and 1 <= dt_min_us <= dt_max_us and max_motion_px > 0):
        raise ValueError(f"bad motion clock arguments t0={t0_us} t1={t1_us} "
                         f"dt=[{dt_min_us},{dt_max_us}] max_motion_px={max_motion_px}")
    st = stats if stats is not None else SamplerStats()
    t = int(t0_us)
    cur = project(t)
    yield t
    dt = int(dt_init_us or dt_min_us)
    while t < t1_us:
        dt = int(min(max(dt, dt_min_us), dt_max_us, t1_us - t))
        nxt = project(t + dt)
        m = motion(cur, nxt)
        if m > max_motion_px and dt > dt_min_us:
            st.rejected += 1
            dt = max(dt_min_us, int(dt * max(0.2, 0.9 * max_motion_px / m)))
            continue
        if m > max_motion_px:
            st.forced += 1
        else:
            st.max_change = max(st.max_change, m)
        st.step(dt)
        t, cur = t + dt, nxt
        yield t
        dt = max(dt_min_us, int(dt * (2.0 if m <= 0 else min(2.0, 0.9 * max_motion_px / m))))


# ---------------------------------------------------------------- per-tile clocks
@dataclass
class _Window:
    t_start: int
    t_end: int
    cand: object             # TileCandidates
    static: np.ndarray       # (n_tiles,) bool: no candidate, or none of them moves
    speed_px_per_us: np.ndarray


@dataclass
class TileSampler:
    """Per-tile adaptive sampling of a rendered trajectory (see module docstring).

    renderer : a :class:`gs2e.splat.forward.ForwardRenderer` (``render``,
        ``render_tiles``, ``candidates``, ``image``, ``n_tiles``).
    pose_at : t_us (int) -> (4, 4) c2w.
    t0_us, t1_us : the span simulated.
    bound : bound on the per-pixel change of G = log(L + log_eps) between a
        tile's consecutive samples.
    dt_min_us : the smallest step (the dyadic quantum); dt_max_us : the
        largest step of a tile whose Gaussians move.
    dt_init_us : first step of every tile (rounded down to dt_min_us * 2^k).
    max_motion_px : optional bound on the motion of a tile's Gaussians
        between its samples (None = off).
    window_motion_px : motion of projected centres between the poses a
        candidate window is built from (smaller: shorter candidate lists, more
        windows).
    batch_intervals : accepted tile intervals handed over per batch.
    """

    renderer: object
    pose_at: Callable[[int], np.ndarray]
    t0_us: int
    t1_us: int
    bound: float
    log_eps: float
    dt_min_us: int = 20
    dt_max_us: int = 20000
    dt_init_us: int = 400
    max_motion_px: float | None = None
    window_motion_px: float = 8.0
    window_poses: int = 5
    batch_intervals: int = 2048
    stats: SamplerStats = field(default_factory=SamplerStats)

    def __post_init__(self):
        r = self.renderer
        if not (self.t1_us > self.t0_us and 1 <= self.dt_min_us <= self.dt_max_us and self.bound > 0):
            raise ConfigError(f"events.sampling: need t1 > t0, 1 <= dt_min_us <= dt_max_us and a "
                              f"positive bound (t0={self.t0_us}, t1={self.t1_us}, "
                              f"dt=[{self.dt_min_us}, {self.dt_max_us}], bound={self.bound})")
        self.H, self.W = r.height, r.width
        self.n_tiles = r.n_tiles
        self.q = int(self.dt_min_us)
        self.max_lvl = max(0, int(math.floor(math.log2(max(1, self.dt_max_us // self.q)))))
        lvl0 = int(math.floor(math.log2(max(1, int(self.dt_init_us) // self.q))))
        self.lvl = np.full(self.n_tiles, min(lvl0, self.max_lvl), np.int64)
        self.t_last = np.full(self.n_tiles, int(self.t0_us), np.int64)
        self.n_samples = np.zeros(self.n_tiles, np.int64)
        self.pending: dict[int, list] = {}
        self.windows: list[_Window] = []
        self._win_len_us = self.q << self.max_lvl  # dyadic, so window ends are aligned
        self.g_last = np.zeros((self.H, self.W), np.float32)
        self.lum0: np.ndarray | None = None
        self._motion_px = -1.0 if self.max_motion_px is None else float(self.max_motion_px)

    # -- windows of candidate Gaussians
    def _window(self, t_us: int) -> _Window:
        for w in self.windows:
            if w.t_start <= t_us <= w.t_end:
                return w
        length = self._win_len_us
        while True:
            start = self.t0_us + ((t_us - self.t0_us) // length) * length
            end = min(self.t1_us, start + length)
            times = np.unique(np.linspace(start, end, self.window_poses).round().astype(np.int64))
            poses = [self.pose_at(int(t)) for t in times]
            cand = self.renderer.candidates(poses, margin_px=1.0,
                                            border_px=4.0 * self.window_motion_px)
            moved = cand.max_step_px
            if moved > 2.0 * self.window_motion_px and length > self.q:
                length = max(self.q, length // 2)
                continue
            break
        grow = moved < 0.5 * self.window_motion_px and length < (self.q << 40)
        self._win_len_us = length * 2 if grow else length
        pose_dt = max(1.0, float(times[1] - times[0])) if len(times) > 1 else 1.0
        empty = np.diff(cand.offsets) == 0
        w = _Window(int(start), int(end), cand, empty | (cand.speed_px == 0.0),
                    cand.speed_px / pose_dt)
        self.windows.append(w)
        self.stats.windows += 1
        return w

    def _drop_windows(self) -> None:
        lo = int(self.t_last.min())
        self.windows = [w for w in self.windows if w.t_end >= lo]

    # -- the schedule
    def _static_until(self, k: int, t: int) -> int:
        """End of the run of consecutive windows, from the one holding t, in
        which tile k is static: its image cannot change before then."""
        w = self._window(t)
        while w.static[k] and w.t_end < self.t1_us:
            w = self._window(int(w.t_end) + 1)
        return int(w.t_end) if w.static[k] else max(t + self.q, int(w.t_start))

    def _next_time(self, k: int, change: float, step: int) -> int:
        """Next sample time of tile k after an accepted step of ``step`` us
        with change ``change`` (sets its level)."""
        t = int(self.t_last[k])
        if t >= self.t1_us:
            return self.t1_us
        rel = t - self.t0_us
        pend = self.pending.get(k)
        w = self._window(t)
        if change == 0.0 and not pend and w.static[k]:
            return self._static_until(k, t)
        new = _next_level(int(self.lvl[k]), step, change, rel, self.q, self.max_lvl,
                          self.dt_max_us, self.bound, self._motion_px, w.speed_px_per_us[k])
        if pend:
            while new > 0 and t + (self.q << new) > pend[0][0]:
                new -= 1
        self.lvl[k] = new
        return min(t + (self.q << new), self.t1_us)

    def __iter__(self) -> Iterator[TileBatch]:
        """Yield batches of accepted tile intervals (in time order per tile)."""
        r, st = self.renderer, self.stats
        eps = self.log_eps
        first = r.render(self.pose_at(self.t0_us))
        st.renders += 1
        st.tiles_rendered += self.n_tiles
        st.pixel_samples += self.n_tiles * TILE * TILE
        self.lum0 = np.empty((self.H, self.W), np.float32)
        image_luminance(first, self.lum0)
        self.g_last[:] = np.log(self.lum0.astype(np.float64) + eps)
        t_next = np.minimum(self.t0_us + (self.q << self.lvl), self.t1_us).astype(np.int64)
        for k in np.flatnonzero(self._window(self.t0_us).static):
            t_next[k] = self._static_until(int(k), self.t0_us)
        out: list[tuple] = []  # accepted intervals, chunks in time order
        n_out = 0
        lum = np.empty((self.n_tiles, TILE, TILE), np.float32)
        g_new = np.empty((self.n_tiles, TILE, TILE), np.float32)
        change = np.empty(self.n_tiles)
        while True:
            active = self.t_last < self.t1_us
            if not active.any():
                break
            T = int(t_next[active].min())
            due = np.flatnonzero(active & (t_next == T))
            cached = [k for k in due if self.pending.get(k) and self.pending[k][0][0] == T]
            render = np.setdiff1d(due, np.asarray(cached, np.int64), assume_unique=True)
            results: dict[int, tuple] = {}
            if len(render):
                w = self._window(T)
                img = r.render_tiles(self.pose_at(T), render, w.cand)
                n = len(render)
                tile_samples(img, render, self.H, self.W, eps, self.g_last, lum[:n], g_new[:n],
                             change[:n])
                st.renders += 1
                st.tiles_rendered += n
                st.pixel_samples += n * TILE * TILE
                # the common case in bulk: accepted, no pending trial, not static at zero change
                ch, step = change[:n], T - self.t_last[render]
                fast = ~((ch > self.bound) & (step > self.q)) & ~((ch == 0.0) & w.static[render])
                if self.pending:
                    fast &= np.array([int(k) not in self.pending for k in render])
                i_fast = np.flatnonzero(fast)
                if len(i_fast):
                    n_out += self._accept_bulk(T, w, render[i_fast], i_fast, ch[i_fast],
                                               step[i_fast], lum, g_new, t_next, out)
                for i in np.flatnonzero(~fast):
                    results[int(render[i])] = (lum[i].copy(), g_new[i].copy(), float(change[i]),
                                               False)
            for k in cached:
                _, lm, gm = self.pending[k].pop(0)
                results[int(k)] = (lm, gm, float(_tile_change(gm, self.g_last, k, self.H, self.W)), True)
            for k, (lm, gm, ch, reused) in results.items():
                step = T - int(self.t_last[k])
                if ch > self.bound and step > self.q:
                    if not reused:
                        st.rejected += 1
                    self.pending.setdefault(k, []).insert(0, (T, lm, gm))
                    # a shorter dyadic step: towards the one that would just meet the
                    # bound (locally linear signal), at most 5x shorter
                    shrink = max(0.2, 0.9 * self.bound / ch) * step
                    lvl = min(int(math.floor(math.log2(max(1.0, shrink / self.q)))),
                              int(math.floor(math.log2((step - 1) / self.q))))
                    lvl = max(0, lvl)
                    while lvl > 0 and (int(self.t_last[k]) - self.t0_us) % (self.q << lvl):
                        lvl -= 1
                    self.lvl[k] = lvl
                    t_next[k] = int(self.t_last[k]) + (self.q << lvl)
                    continue
                if ch > self.bound:
                    st.forced += 1
                else:
                    st.max_change = max(st.max_change, ch)
                st.reused += int(reused)
                st.accepted += 1
                st.step(step)
                self.n_samples[k] += 1
                out.append((np.array([k]), self.t_last[k:k + 1].copy(), np.array([T]),
                            self.n_samples[k:k + 1].copy(), lm[None]))
                n_out += 1
                ty, tx = divmod(k, r.tiles_x)
                y0, x0 = ty * TILE, tx * TILE
                y1, x1 = min(self.H, y0 + TILE), min(self.W, x0 + TILE)
                self.g_last[y0:y1, x0:x1] = gm[:y1 - y0, :x1 - x0]
                self.t_last[k] = T
                pend = self.pending.get(k)
                if pend is not None:
                    while pend and pend[0][0] <= T:
                        pend.pop(0)
                    if not pend:
                        del self.pending[k]
                t_next[k] = self._next_time(k, ch, step)
            if n_out >= self.batch_intervals:
                yield self._batch(out)
                out, n_out = [], 0
                self._drop_windows()
        if out:
            yield self._batch(out)

    def _accept_bulk(self, T, w, tiles, idx, change, step, lum, g_new, t_next, out) -> int:
        """Accept the samples at T of ``tiles`` (rows ``idx`` of lum/g_new),
        none of which has a pending trial or is static at zero change."""
        st = self.stats
        over = change > self.bound
        st.forced += int(over.sum())
        if not over.all():
            st.max_change = max(st.max_change, float(change[~over].max()))
        st.accepted += len(tiles)
        st.step(int(step.min()))
        st.step(int(step.max()))
        self.n_samples[tiles] += 1
        out.append((tiles, self.t_last[tiles], np.full(len(tiles), T, np.int64),
                    self.n_samples[tiles], lum[idx]))
        _commit_tiles(g_new, idx, tiles, self.g_last)
        self.t_last[tiles] = T
        _next_levels(tiles, change, step, T, self.t0_us, self.t1_us, self.q, self.max_lvl,
                     self.dt_max_us, self.bound, self._motion_px, w.speed_px_per_us, self.lvl,
                     t_next)
        return len(tiles)

    @staticmethod
    def _batch(out: list[tuple]) -> TileBatch:
        """One batch from chunks of accepted intervals (tiles, t0, t1, key_idx,
        lum), in time order: per tile in time order, tiles ascending."""
        tiles, t0, t1, key, lum = (np.concatenate(c) for c in zip(*out))
        order = np.argsort(tiles, kind="stable")
        uniq, counts = np.unique(tiles, return_counts=True)
        offsets = np.zeros(len(uniq) + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        return TileBatch(uniq, offsets, t0[order], t1[order], key[order], lum[order])
