"""Streaming pixel models: DVS-Voltmeter (stochastic) and ideal (ESIM-style).

Frame-source protocol
---------------------
A frame source is any iterable of ``(t_us, frame)``: ``t_us`` an integer time
in microseconds (strictly increasing), ``frame`` a float32 (H, W) array of
LINEAR luminance in [0, 1] (no gamma, no log). The render stage can feed its
frames directly; :mod:`gs2e.events.frames` adapts images, videos and arrays.
Each model converts to its own units (the DVS presets use 0..255, see
:mod:`gs2e.events.presets`).

Events
------
:class:`Events`: ``t`` int64 microseconds (absolute, sorted), ``x``, ``y``
uint16 pixel column / row, ``p`` uint8 polarity, 1 = ON (brightness up),
0 = OFF (DSEC convention).

DVS-Voltmeter: timing of a crossing given its polarity
------------------------------------------------------
Voltage V(t) = v0 + mu t + sigma W(t), barriers at +theta_on (ON) and
-theta_off (OFF); distances a = theta_on - v0, b = theta_off + v0. The
polarity is drawn with the exact two-barrier probability
p_on = (e^{zb} - 1) / (e^{zb} - e^{-za}), z = 2 mu / sigma^2 (computed with
expm1, no overflow; limit b / (a + b) at mu = 0). The time is then drawn, as in
DVS-Voltmeter, from the first-passage law of the chosen barrier alone, at
distance eps (a or b), with the drift component towards it c (= mu for ON,
-mu for OFF):

* c > 0: IG(mean eps / c, shape eps^2 / sigma^2) (Michael-Schucany-Haas).
* c = 0: Levy(scale eps^2 / sigma^2).
* c < 0 (drift away from the barrier): the barrier is reached only with
  probability exp(-2 |c| eps / sigma^2); the defective density is
  f_c(t) = eps / (sigma sqrt(2 pi t^3)) exp(-(eps - c t)^2 / (2 sigma^2 t)).
  Since (eps - c t)^2 = (eps + c t)^2 - 4 c eps t,
  f_c(t) = exp(2 c eps / sigma^2) f_{|c|}(t): conditional on hitting, the time
  is IG(mean eps / |c|, shape eps^2 / sigma^2), i.e. exactly the law for drift
  +|c|. (The public code plugs c < 0 into the sampler and truncates a normal,
  which is biased.) We therefore sample with |c| in all cases.

Option ``exit_law="two_barrier"`` instead simulates the exact exit of the
drift-diffusion from the band (-theta_off, theta_on), per interval: end point
y ~ N(v + mu s, sigma^2 s); no exit with the bridge's probability of staying
in the band (image series); otherwise the side and time are drawn by rejection
from the single-barrier bridge laws (side weights = their crossing
probabilities, time by the bridge time change) with acceptance ratio
g_two / g_single (image series). Polarities then follow p_on and exit times
the series density g_+ below, exactly.

This is the single-barrier law conditional on hitting that barrier. It is NOT
the law of the exit time of the two-barrier problem conditional on exiting
through that barrier: that one excludes paths that touch the other barrier
first and has the image-series density
g_+(t) = sum_k (a + 2 k w) / (sigma sqrt(2 pi t^3))
         exp(mu a / sigma^2 - mu^2 t / (2 sigma^2) - (a + 2 k w)^2 / (2 sigma^2 t)) / p_on,
w = a + b, which is shorter-tailed. DVS-Voltmeter (and the paper) define
the model with the single-barrier law; gs2e follows the model and documents
the difference (tests check both statements numerically, see
tests/test_events_voltmeter.py).

Residual at the frame end: if the sampled crossing falls after the frame end
t1, the voltage at t1 is drawn from the path conditioned on that crossing
time tau: the distance to the barrier is a 3-d Bessel bridge from eps to 0
over [0, tau] (exact for a first-passage path given tau; the drift drops out),
i.e. |(eps (1 - s/tau) + sd Z1, sd Z2, sd Z3)| with sd^2 = sigma^2 s (tau - s)/tau.
The public code interpolates linearly (eps s / tau) instead. The process
restarts from that residual with the next frame's drift (Markov property).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from gs2e.common.errors import InputError, ConfigError
from gs2e.common.registry import PluginRegistry, add
from gs2e.common.settings import require
from gs2e.events import _kernels as K
from gs2e.events.presets import Preset, effective_threshold, get_preset
from gs2e.events.sensors import resolve_noise
from gs2e.events.settings import EventSettings

log = logging.getLogger("gs2e.events")


@dataclass
class Events:
    """A time-sorted batch of events (see module docstring for units)."""

    t: np.ndarray  # int64 us
    x: np.ndarray  # uint16
    y: np.ndarray  # uint16
    p: np.ndarray  # uint8, 1 = ON, 0 = OFF

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @staticmethod
    def empty() -> "Events":
        return Events(np.empty(0, np.int64), np.empty(0, np.uint16),
                      np.empty(0, np.uint16), np.empty(0, np.uint8))

    @staticmethod
    def concat(batches: Iterable["Events"]) -> "Events":
        b = [e for e in batches if len(e)]
        if not b:
            return Events.empty()
        return Events(np.concatenate([e.t for e in b]), np.concatenate([e.x for e in b]),
                      np.concatenate([e.y for e in b]), np.concatenate([e.p for e in b]))


# ---------------------------------------------------------------- thresholds
def sample_sequence_theta(rng: np.random.Generator, theta_on: float, theta_off: float,
                          sampling: str = "fixed", theta_range=(0.2, 0.5),
                          independent: bool = False) -> tuple[float, float]:
    """Per-sequence nominal thresholds.

    ``sampling``: "fixed" (theta_on, theta_off as given), "uniform" or
    "loguniform" in ``theta_range`` (paper: [0.2, 0.5]); ``independent``: draw
    ON and OFF separately, else one value for both.
    """
    if sampling == "fixed":
        return float(theta_on), float(theta_off)
    lo, hi = float(theta_range[0]), float(theta_range[1])
    if not (0 < lo <= hi):
        raise ConfigError(f"events.theta_range: need 0 < low <= high, got {list(theta_range)}")

    def draw() -> float:
        if sampling == "uniform":
            return float(rng.uniform(lo, hi))
        if sampling == "loguniform":
            return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        raise ConfigError(f"events.theta_sampling: unknown '{sampling}'")

    a = draw()
    return (a, draw()) if independent else (a, a)


def threshold_map(rng: np.random.Generator, shape: tuple[int, int], theta: float,
                  sigma: float, floor_frac: float = 0.05) -> np.ndarray:
    """Per-pixel thresholds ~ Normal(theta, sigma) truncated to values >=
    floor_frac * theta (redrawn, so they stay positive). float64 (H, W)."""
    if theta <= 0:
        raise ConfigError(f"events: contrast threshold must be > 0, got {theta}")
    out = np.full(shape, float(theta), dtype=np.float64)
    if sigma <= 0:
        return out
    out = rng.normal(theta, sigma, size=shape)
    floor = floor_frac * theta
    for _ in range(1000):
        bad = out < floor
        nb = int(bad.sum())
        if nb == 0:
            break
        out[bad] = rng.normal(theta, sigma, size=nb)
    return np.maximum(out, floor)


def theta_summary(th: np.ndarray) -> dict:
    """mean, std, min, max of a threshold map."""
    return {"mean": float(th.mean()), "std": float(th.std()),
            "min": float(th.min()), "max": float(th.max())}


# ---------------------------------------------------------------- models
TILE = 16  # pixels per tile side: the rasterizer's tiles, the unit of sampling


@dataclass
class TileBatch:
    """Sample intervals of some tiles (what the models consume).

    ``tiles`` (m,) int64 tile numbers (row-major, TILE x TILE px); slot s holds
    the intervals ``offsets[s]`` .. ``offsets[s + 1] - 1`` of tile tiles[s],
    consecutive in time. Per interval: ``t0_us``, ``t1_us`` (int64, absolute
    microseconds, t0 = the tile's previous sample time), ``key_idx`` (int64:
    index of the end sample in the tile's sequence, the first sample being 0;
    it keys the random streams) and ``lum`` (TILE, TILE) linear luminance in
    [0, 1] at t1, float32 or float64 (rows/columns beyond the image are ignored).
    """

    tiles: np.ndarray
    offsets: np.ndarray
    t0_us: np.ndarray
    t1_us: np.ndarray
    key_idx: np.ndarray
    lum: np.ndarray

    def __len__(self) -> int:
        return int(self.t0_us.shape[0])

    @property
    def pixel_samples(self) -> int:
        """Rendered pixel values the batch consumed (TILE^2 per interval)."""
        return len(self) * TILE * TILE

    @staticmethod
    def from_frames(ts_us: np.ndarray, frames: np.ndarray, key0: int) -> "TileBatch":
        """Every tile of B frames ((B + 1,) int64 times incl. the previous
        frame's, (B, H, W) luminance); interval b of every tile is keyed
        ``key0 + b``."""
        B, H, W = frames.shape
        n_t = -(-H // TILE) * -(-W // TILE)
        lum = np.empty((n_t * B, TILE, TILE), frames.dtype)
        K.frames_to_tiles(np.ascontiguousarray(frames), lum)
        ts = np.asarray(ts_us, np.int64)
        return TileBatch(np.arange(n_t, dtype=np.int64), np.arange(n_t + 1, dtype=np.int64) * B,
                         np.tile(ts[:-1], n_t), np.tile(ts[1:], n_t),
                         np.tile(np.arange(key0, key0 + B, dtype=np.int64), n_t), lum)


def _event_buffers(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-slot event buffers of ``n`` entries: time offset (float64 us), x, y
    (int32), polarity (int8, +1/-1)."""
    return np.empty(n, np.float64), np.empty(n, np.int32), np.empty(n, np.int32), np.empty(n, np.int8)


class _StreamingModel:
    """Common validation, tile batches, buffers, noise and time ordering.

    Frames and tile batches may be mixed: a frame is an interval of every
    tile. Events come out sorted by time, ties by pixel (row, then column),
    then in the order they were emitted; a call returns the events before
    the horizon (the earliest time a later interval can start: the least
    recent tile sample) and keeps the rest for the next call or
    :meth:`flush`. Results do not depend on how samples are batched.
    """

    name = "base"
    _frame_dtype = np.float32  # what frames are converted to; one kernel signature each

    def __init__(self, shape: tuple[int, int], theta_on: float | np.ndarray = 1.0,
                 theta_off: float | np.ndarray = 1.0, refractory_us: float = 0.0,
                 leak_rate_hz: float = 0.0, shot_noise_rate_hz: float = 0.0,
                 shot_noise_on_fraction: float = 0.5, seed: int = 0,
                 max_events_per_pixel: int = 10000, source: str = "frames",
                 leak_light_rate_hz: float = 0.0, lum_max: float = 1.0):
        H, W = int(shape[0]), int(shape[1])
        if H < 1 or W < 1 or W > 65535 or H > 65535:
            raise ConfigError(f"events: invalid frame shape {shape}")
        self.shape = (H, W)
        self.tiles_x, self.tiles_y = -(-W // TILE), -(-H // TILE)
        self.n_tiles = self.tiles_x * self.tiles_y
        self.th_on = self._theta(theta_on, "theta_on")
        self.th_off = self._theta(theta_off, "theta_off")
        if refractory_us < 0 or leak_rate_hz < 0 or shot_noise_rate_hz < 0 or leak_light_rate_hz < 0:
            raise ConfigError("events: refractory_us and noise rates must be >= 0")
        if not 0.0 <= shot_noise_on_fraction <= 1.0:
            raise ConfigError("events.shot_noise_on_fraction must be in [0, 1]")
        if max_events_per_pixel < 1:
            raise ConfigError("events.max_events_per_pixel must be >= 1")
        self.refractory_us = float(refractory_us)
        self.leak_rate_hz = float(leak_rate_hz)
        self.leak_light_rate_hz = float(leak_light_rate_hz)
        if not lum_max >= 1.0:
            raise ConfigError(f"events: lum_max (the light's largest scale) must be >= 1, got {lum_max}")
        self.lum_max = float(lum_max)  # bound of the luminance the noise's rates follow
        self.shot_noise_rate_hz = float(shot_noise_rate_hz)
        self.shot_noise_on_fraction = float(shot_noise_on_fraction)
        self.seed = int(seed) & 0xFFFFFFFFFFFFFFFF
        self.max_events_per_pixel = int(max_events_per_pixel)
        self.source = source
        self.n_frames = 0          # frames consumed (frame API)
        self.t_prev: int | None = None  # last frame time (frame API)
        self.t_tile: np.ndarray | None = None   # per tile: time of its last sample
        self.n_tile = np.zeros(self.n_tiles, np.int64)  # per tile: samples so far
        self.prev = np.zeros(self.shape)  # per pixel: luminance of its last sample
        self._prev2 = np.zeros(self.shape)
        self.cap = 0               # signal events reserved per slot
        self.noise_cap = 0         # noise events reserved per slot (its own buffers: far fewer)
        self._ev_t, self._ev_x, self._ev_y, self._ev_p = _event_buffers(0)
        self._nz_t, self._nz_x, self._nz_y, self._nz_p = _event_buffers(0)
        self.n_capped = 0
        self.intervals = 0         # tile intervals simulated
        self._carry = Events.empty()  # events at or after the horizon

    def _theta(self, th, key) -> np.ndarray:
        a = np.asarray(th, dtype=np.float64)
        if a.ndim == 0:
            a = np.full(self.shape, float(a))
        if a.shape != self.shape:
            raise ConfigError(f"events.{key}: map shape {a.shape} != frame shape {self.shape}")
        if not np.all(np.isfinite(a)) or np.any(a <= 0):
            raise ConfigError(f"events.{key}: thresholds must be finite and > 0")
        return np.ascontiguousarray(a)

    def _ensure(self, cap: int, m: int) -> None:
        """Room for ``cap`` signal events in each of ``m`` slots."""
        if cap > self.cap or m * max(cap, self.cap) > self._ev_t.shape[0]:
            self.cap = max(cap, self.cap)
            self._ev_t, self._ev_x, self._ev_y, self._ev_p = _event_buffers(m * self.cap)

    def _ensure_noise(self, cap: int, m: int) -> None:
        """Room for ``cap`` noise events in each of ``m`` slots."""
        if cap > self.noise_cap or m * max(cap, self.noise_cap) > self._nz_t.shape[0]:
            self.noise_cap = max(cap, self.noise_cap)
            self._nz_t, self._nz_x, self._nz_y, self._nz_p = _event_buffers(m * self.noise_cap)

    @property
    def noise_on(self) -> bool:
        return self.leak_rate_hz > 0 or self.shot_noise_rate_hz > 0 or self.leak_light_rate_hz > 0

    @property
    def horizon_us(self) -> int | None:
        """No later interval starts before this time (the least recent tile sample)."""
        return None if self.t_tile is None else int(self.t_tile.min())

    def _check_frames(self, ts_us, frames) -> tuple[np.ndarray, np.ndarray]:
        """Validate frames: integer, strictly increasing times; (B, H, W)
        finite values in [0, 1]. Returns (int64 times, frames of ``_frame_dtype``)."""
        first = self.n_frames + 1  # 1-based number of the batch's first frame
        ts = np.asarray(ts_us)
        if ts.ndim != 1:
            raise InputError(f"{self.source}: timestamps must be a 1-d sequence")
        if not (np.issubdtype(ts.dtype, np.integer) or
                (np.issubdtype(ts.dtype, np.floating) and np.all(np.isfinite(ts))
                 and np.all(ts == np.round(ts)))):
            raise InputError(f"{self.source}: timestamps near frame {first} are not integer "
                             f"microseconds (got {ts[:3].tolist()}...)")
        ts = ts.astype(np.int64)
        f = np.asarray(frames)
        if f.ndim != 3 or f.shape[1:] != self.shape or f.shape[0] != ts.shape[0]:
            raise InputError(f"{self.source}: frames near frame {first} have shape "
                             f"{f.shape[1:] if f.ndim == 3 else f.shape}, expected "
                             f"{self.shape} (H, W), one per timestamp")
        if not np.issubdtype(f.dtype, np.number) or np.issubdtype(f.dtype, np.complexfloating):
            raise InputError(f"{self.source}: frames are not real numbers ({f.dtype})")
        f = np.ascontiguousarray(f, dtype=self._frame_dtype)
        lo, hi = K.frame_ranges(f)
        finite = np.isfinite(lo) & np.isfinite(hi)
        if not finite.all():
            i = int(np.argmin(finite))
            raise InputError(f"{self.source}: frame {first + i} (t={ts[i]} us) has NaN or "
                             f"infinite values")
        bad = (lo < 0.0) | (hi > self.lum_max * (1.0 + 1e-6))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{self.source}: frame {first + i} (t={ts[i]} us) has values in "
                             f"[{lo[i]:g}, {hi[i]:g}]; expected linear luminance in [0, {self.lum_max:g}]"
                             + (" (the light's largest scale)" if self.lum_max > 1 else ""))
        prev = np.concatenate([[self.t_prev], ts]) if self.t_prev is not None else ts
        dif = np.diff(prev)
        if np.any(dif <= 0):
            i = int(np.argmax(dif <= 0))
            raise InputError(f"{self.source}: timestamps must increase strictly; got "
                             f"t={prev[i + 1]} us after t={prev[i]} us")
        if (hi > self.lum_max).any():  # within rounding of the bound: onto it
            f = np.minimum(f, f.dtype.type(self.lum_max))
        return ts, f

    def start(self, t_us: int, frame: np.ndarray) -> None:
        """The first sample of every tile: (H, W) linear luminance at ``t_us``."""
        ts, f = self._check_frames([t_us], np.asarray(frame)[None])
        self._start(int(ts[0]), f[0])

    def _start(self, t_us: int, f: np.ndarray) -> None:
        if self.t_tile is not None:
            raise InputError(f"{self.source}: the model was already started")
        self._init_state(f)
        self.prev[:] = f
        self.t_tile = np.full(self.n_tiles, t_us, np.int64)
        self.t_prev, self.n_frames = t_us, 1

    def process(self, t_us: int, frame: np.ndarray) -> Events:
        """Feed one frame; returns the events before the horizon (see the class
        docstring; none for the first frame, which only sets the state)."""
        return self.process_batch([t_us], np.asarray(frame)[None])

    def process_batch(self, ts_us, frames) -> Events:
        """Feed B frames at once ((B,) int us, (B, H, W) linear luminance): each
        is one interval of every tile. Returns the events before the horizon."""
        ts, f = self._check_frames(ts_us, frames)
        if self.t_tile is None:
            self._start(int(ts[0]), f[0])
            ts, f = ts[1:], f[1:]
            if len(ts) == 0:
                return Events.empty()
        if not np.all(self.t_tile == self.t_prev):
            raise InputError(f"{self.source}: frames cannot follow tile samples")
        batch = TileBatch.from_frames(np.concatenate([[self.t_prev], ts]), f, self.n_frames)
        self.t_prev = int(ts[-1])
        self.n_frames += len(ts)
        return self.process_tiles(batch)

    def process_tiles(self, b: TileBatch) -> Events:
        """Feed a :class:`TileBatch`; returns the events before the horizon."""
        if self.t_tile is None:
            raise InputError(f"{self.source}: start() the model with a first frame")
        m, n = len(b.tiles), len(b)
        if m == 0:
            return Events.empty()
        tiles = np.ascontiguousarray(b.tiles, np.int64)
        off = np.ascontiguousarray(b.offsets, np.int64)
        t0 = np.ascontiguousarray(b.t0_us, np.int64)
        t1 = np.ascontiguousarray(b.t1_us, np.int64)
        key = np.ascontiguousarray(b.key_idx, np.int64)
        lum = np.ascontiguousarray(b.lum)
        if lum.dtype not in (np.float32, np.float64):
            lum = lum.astype(self._frame_dtype)
        first = off[:-1]
        if (tiles.min() < 0 or tiles.max() >= self.n_tiles or len(np.unique(tiles)) != m
                or off[0] != 0 or off[-1] != n or np.any(np.diff(off) < 1)
                or lum.shape != (n, TILE, TILE)):
            raise InputError(f"{self.source}: malformed tile batch")
        inner = np.ones(n, bool)
        inner[first] = False
        if not (np.all(t1 > t0) and np.all(t0[first] == self.t_tile[tiles])
                and np.all(t0[1:][inner[1:]] == t1[:-1][inner[1:]])):
            raise InputError(f"{self.source}: the intervals of a tile must follow its last "
                             "sample and each other in time")
        batch = K.TileIntervals(tiles, off, t0, t1, key, lum)
        grid = K.Grid(*self.shape, TILE)
        fn = np.zeros(n, np.int64)
        fn_noise = np.zeros(n, np.int64)
        per_slot = int(np.diff(off).max())
        # signal and noise each rerun (on the same input) only when their own
        # buffer was too small
        self._ensure(max(64, per_slot * TILE * TILE // 4), m)
        state_in, state_out = self._states()
        while True:
            signal = K.EventSlots(self.cap, self._ev_t, self._ev_x, self._ev_y, self._ev_p, fn)
            n_cap = self._run_signal(batch, grid, state_in, state_out, signal)
            need = np.add.reduceat(fn, first).max()
            if need <= self.cap:
                break
            self._ensure(int(need * 1.25) + 16, m)
        if self.noise_on:
            self._ensure_noise(16, m)
            params = K.NoiseParams(self.seed, self.leak_rate_hz, self.shot_noise_rate_hz,
                                   self.shot_noise_on_fraction,
                                   K.noise_block_us(self.leak_rate_hz + self.leak_light_rate_hz * self.lum_max,
                                                    self.shot_noise_rate_hz, TILE),
                                   self.leak_light_rate_hz, self.lum_max)
        while True:
            noise = K.EventSlots(self.noise_cap, self._nz_t, self._nz_x, self._nz_y, self._nz_p,
                                 fn_noise)
            if not self.noise_on:
                break
            K.noise_tiles(batch, grid, self.prev, params, noise)
            need = np.add.reduceat(fn_noise, first).max()
            if need <= self.noise_cap:
                break
            self._ensure_noise(int(need * 1.25) + 16, m)
        self.n_capped += int(n_cap)
        K.commit_tiles(tiles, grid, state_out, state_in)
        total = int(fn.sum() + fn_noise.sum())
        ev = Events(np.empty(total, np.int64), np.empty(total, np.uint16),
                    np.empty(total, np.uint16), np.empty(total, np.uint8))
        K.gather_tiles(batch, signal, noise, ev.t, ev.x, ev.y, ev.p)
        last = off[1:] - 1
        self.t_tile[tiles] = t1[last]
        self.n_tile[tiles] += np.diff(off)
        self.intervals += n
        return self._release(Events.concat([self._carry, ev]), self.horizon_us)

    def _release(self, ev: Events, horizon: int | None) -> Events:
        """Sort by (time, row, column), stable; keep events at/after ``horizon``."""
        if len(ev) == 0:
            self._carry = ev
            return ev
        ev = Events(*K.sort_events(ev.t, ev.x, ev.y, ev.p, *self.shape))
        cut = len(ev) if horizon is None else int(np.searchsorted(ev.t, horizon, side="left"))
        self._carry = Events(ev.t[cut:], ev.x[cut:], ev.y[cut:], ev.p[cut:])
        return Events(ev.t[:cut], ev.x[:cut], ev.y[:cut], ev.p[:cut])

    def simulate(self, ts_us, frames) -> Events:
        """All events of an in-memory frame sequence (:meth:`process_batch`
        then :meth:`flush`)."""
        return Events.concat([self.process_batch(ts_us, frames), self.flush()])

    def flush(self) -> Events:
        """The events kept back at the horizon (call once, after the last sample)."""
        return self._release(self._carry, None)

    def run(self, source: Iterable[tuple[int, np.ndarray]], batch: int = 32) -> Iterator[Events]:
        """Events of a frame source, one time-sorted batch per ``batch`` frames
        (streaming: memory does not grow with the sequence length)."""
        ts, fr = [], []
        for t_us, frame in source:
            ts.append(t_us)
            fr.append(frame)
            if len(ts) == batch:
                yield self.process_batch(ts, np.stack(fr))
                ts, fr = [], []
        if ts:
            yield self.process_batch(ts, np.stack(fr))
        yield self.flush()

    def metadata(self) -> dict:
        return {"model": self.name, "seed": self.seed, "refractory_us": self.refractory_us,
                "leak_rate_hz": self.leak_rate_hz, "leak_light_rate_hz": self.leak_light_rate_hz,
                "shot_noise_rate_hz": self.shot_noise_rate_hz,
                "shot_noise_on_fraction": self.shot_noise_on_fraction,
                "theta_on_map": theta_summary(self.th_on),
                "theta_off_map": theta_summary(self.th_off),
                "max_events_per_pixel": self.max_events_per_pixel,
                "pixel_intervals_capped": self.n_capped, "n_frames": self.n_frames,
                "tile_intervals": self.intervals}

    # what a model declares (the registry, :data:`MODELS`, reads these)
    name = ""

    @classmethod
    def from_config(cls, cfg: EventSettings, shape, **common) -> "_StreamingModel":
        """The model for a validated ``events`` section; ``common``: the keyword
        arguments every model takes (thresholds, noise, seed, caps)."""
        raise NotImplementedError

    @classmethod
    def log_contrast(cls, cfg: EventSettings, on: np.ndarray, off: np.ndarray):
        """(step_on, step_off, eps): the log(L + eps) steps that fire an ON /
        OFF event given the model's thresholds ``on`` / ``off`` (:func:`log_contrast`)."""
        raise NotImplementedError

    @classmethod
    def sampling_step(cls, cfg: EventSettings, theta: float) -> float:
        """The smallest log(L + eps) step threshold ``theta`` can fire at (the
        sampling bound's unit)."""
        raise NotImplementedError

    @classmethod
    def log_signal_of(cls, cfg: EventSettings) -> tuple[float, float, float]:
        """(scale, offset, divisor) of this model's log signal log(L * scale +
        offset), whose steps are theta / divisor (an events file's settings
        come back through :func:`gs2e.events.settings.read_settings`)."""
        raise NotImplementedError

    def describe(self, theta_on_nominal: float) -> dict:
        """Extra entries of the run's metadata."""
        return {}

    def file_attrs(self) -> dict:
        """Extra attributes of events.h5 (the resolved parameters, for readers
        outside gs2e)."""
        return {}

    @classmethod
    def config_preset(cls, cfg: EventSettings) -> str | None:
        """The preset the config names, where the model has one (the stats' ``preset``)."""
        return None

    # subclass hooks
    def _init_state(self, f: np.ndarray) -> None: ...
    def _run_signal(self, batch: K.TileIntervals, grid: K.Grid, state_in: K.PixelState,
                    state_out: K.PixelState, slots: K.EventSlots) -> int:
        """Run the model's kernel on ``batch``; returns the capped pixel-intervals."""
        ...

    def _states(self) -> tuple[K.PixelState, K.PixelState]:
        """(state the kernel reads, state it writes) (:func:`K.commit_tiles`
        copies the second into the first for the batch's tiles)."""
        ...


class VoltmeterModel(_StreamingModel):
    """DVS-Voltmeter drift-diffusion pixel model (see module docstring).

    Parameters beyond the common ones: ``preset`` (a :class:`Preset` or its
    name). Thresholds are barrier heights in normalised voltage (1 = nominal).
    """

    name = "voltmeter"

    @staticmethod
    def preset_of(cfg: EventSettings) -> Preset:
        """The config's preset with its ``k1``..``k6`` overrides."""
        return get_preset(cfg.preset, {i: getattr(cfg, f"k{i}") for i in range(1, 7)})

    @classmethod
    def from_config(cls, cfg: EventSettings, shape, **common) -> "VoltmeterModel":
        return cls(shape, preset=cls.preset_of(cfg), exit_law=cfg.exit_law, **common)

    @classmethod
    def log_contrast(cls, cfg: EventSettings, on: np.ndarray, off: np.ndarray):
        # the drift k1 (dL/dt) / (L + k2) integrates to a voltage k1 log(L * scale + k2):
        # a voltage threshold theta is the step theta / k1 of log(L + k2 / scale)
        p = cls.preset_of(cfg)
        return on / p.k[0], off / p.k[0], float(p.k[1] / p.intensity_scale)

    @classmethod
    def sampling_step(cls, cfg: EventSettings, theta: float) -> float:
        # the bright-pixel limit of the voltage threshold, as a log-intensity step
        return float(np.log1p(theta / cls.preset_of(cfg).k[0]))

    @classmethod
    def log_signal_of(cls, cfg: EventSettings) -> tuple[float, float, float]:
        p = cls.preset_of(cfg)
        return float(p.intensity_scale), float(p.k[1]), float(p.k[0])

    def describe(self, theta_on_nominal: float) -> dict:
        p = self.preset
        d = {f"rel_dL_over_L_at_{lum:g}": effective_threshold(p, theta_on_nominal, lum)
             for lum in (0.1, 0.5, 1.0)}
        d["bright_limit"] = theta_on_nominal / p.k[0]
        return {"effective_threshold": d}

    def file_attrs(self) -> dict:
        return {"preset": self.preset.to_dict()}

    @classmethod
    def config_preset(cls, cfg: EventSettings) -> str | None:
        return cfg.preset

    def __init__(self, shape, preset: Preset | str = "dvs346",
                 exit_law: str = "single_barrier", **kw):
        super().__init__(shape, **kw)
        if exit_law not in ("single_barrier", "two_barrier"):
            raise ConfigError(f"events.exit_law: unknown '{exit_law}' "
                              f"(single_barrier or two_barrier)")
        self.exit_law = exit_law
        self.preset = get_preset(preset) if isinstance(preset, str) else preset
        self.k = np.asarray(self.preset.k, dtype=np.float64)
        k = self.k
        if not np.all(np.isfinite(k)) or k[1] <= 0 or k[2] < 0 or k[5] < 0:
            raise ConfigError(f"events: invalid k values {list(k)} (need finite k, k2 > 0, "
                              f"k3 >= 0, k6 >= 0; k4, k5 may have either sign)")
        self.res = np.zeros(self.shape)
        self.ready = np.full(self.shape, -np.inf)
        self._res2 = np.zeros(self.shape)
        self._ready2 = np.full(self.shape, -np.inf)

    def _run_signal(self, batch, grid, state_in, state_out, slots):
        params = K.VoltmeterParams(self.preset.intensity_scale, self.seed, self.k,
                                   self.preset.time_unit_us, self.th_on, self.th_off,
                                   self.refractory_us, self.max_events_per_pixel,
                                   self.exit_law == "two_barrier")
        return K.voltmeter_tiles(batch, grid, params, state_in, state_out, slots)

    def _states(self):
        return (K.PixelState(self.prev, self.res, self.ready),
                K.PixelState(self._prev2, self._res2, self._ready2))

    def metadata(self) -> dict:
        d = super().metadata()
        d["preset"] = self.preset.to_dict()
        d["exit_law"] = self.exit_law
        return d


class IdealModel(_StreamingModel):
    """Ideal (ESIM-style) log-intensity crossing model.

    Log intensity G = log(L + log_eps) with L linear luminance in [0, 1];
    thresholds are log-intensity steps. State: the reference level per pixel
    (kept as the linear value exp(G_ref); :attr:`ref_log` gives G_ref) and
    the time of the last event (refractory).
    """

    name = "ideal"
    # float64 frames: crossing times exact to ~1e-6 us on log-linear input even
    # for slow ramps (float32 luminance would limit that to ~0.01 us)
    _frame_dtype = np.float64

    @classmethod
    def from_config(cls, cfg: EventSettings, shape, **common) -> "IdealModel":
        return cls(shape, log_eps=cfg.log_eps, **common)

    @classmethod
    def log_contrast(cls, cfg: EventSettings, on: np.ndarray, off: np.ndarray):
        return on, off, float(cfg.log_eps)

    @classmethod
    def sampling_step(cls, cfg: EventSettings, theta: float) -> float:
        return float(theta)

    @classmethod
    def log_signal_of(cls, cfg: EventSettings) -> tuple[float, float, float]:
        return 1.0, float(cfg.log_eps), 1.0

    def __init__(self, shape, log_eps: float = 1e-3, **kw):
        super().__init__(shape, **kw)
        if not log_eps > 0:
            raise ConfigError(f"events.log_eps must be > 0, got {log_eps}")
        self.log_eps = float(log_eps)
        self.ref = np.ones(self.shape)
        self.last = np.full(self.shape, -np.inf)
        self._ref2 = np.ones(self.shape)
        self._last2 = np.full(self.shape, -np.inf)

    @property
    def ref_log(self) -> np.ndarray:
        return np.log(self.ref)

    def _init_state(self, f):
        self.ref = f.astype(np.float64) + self.log_eps

    def _run_signal(self, batch, grid, state_in, state_out, slots):
        params = K.IdealParams(self.log_eps, self.th_on, self.th_off, self.refractory_us,
                               self.max_events_per_pixel)
        return K.ideal_tiles(batch, grid, params, state_in, state_out, slots)

    def _states(self):
        return (K.PixelState(self.prev, self.ref, self.last),
                K.PixelState(self._prev2, self._ref2, self._last2))

    def metadata(self) -> dict:
        d = super().metadata()
        d["log_eps"] = self.log_eps
        return d


def make_model(settings: EventSettings, shape: tuple[int, int], seed: int,
               source: str = "frames", lum_max: float = 1.0):
    """Build a model from the ``events`` settings (or the validated section).

    Returns (model, info) with info = the sequence-level draws (nominal theta
    values) for the metadata. The per-sequence theta, the mismatch maps and
    the model's random streams all derive from ``seed``.
    """
    cfg = require(settings, EventSettings, "make_model")
    rng = np.random.default_rng([int(seed), 0x7E7A])
    th_on, th_off = sample_sequence_theta(
        rng, cfg.theta_on, cfg.theta_off, cfg.theta_sampling, cfg.theta_range,
        cfg.theta_on_off_independent)
    # a sensor's mismatch is relative: sigma scales with each polarity's threshold
    noise_on, sources = resolve_noise(cfg, th_on)
    noise_off, _ = resolve_noise(cfg, th_off)
    on_map = threshold_map(rng, shape, th_on, noise_on["theta_mismatch_sigma"])
    off_map = threshold_map(rng, shape, th_off, noise_off["theta_mismatch_sigma"])
    common = dict(theta_on=on_map, theta_off=off_map, refractory_us=noise_on["refractory_us"],
                  leak_rate_hz=noise_on["leak_rate_hz"], leak_light_rate_hz=noise_on["leak_light_rate_hz"],
                  lum_max=float(lum_max),
                  shot_noise_rate_hz=noise_on["shot_noise_rate_hz"],
                  shot_noise_on_fraction=noise_on["shot_noise_on_fraction"], seed=int(seed),
                  max_events_per_pixel=cfg.max_events_per_pixel, source=source)
    model = model_class(cfg.model).from_config(cfg, shape, **common)
    info = {"theta_on_nominal": th_on, "theta_off_nominal": th_off,
            "theta_sampling": cfg.theta_sampling, "theta_range": list(cfg.theta_range),
            "theta_mismatch_sigma": noise_on["theta_mismatch_sigma"],
            "theta_mismatch_sigma_off": noise_off["theta_mismatch_sigma"],
            "noise": noise_on, "noise_sources": sources}
    return model, info


# ----------------------------------------------------------------- the registry
MODELS: dict[str, type[_StreamingModel]] = PluginRegistry("gs2e.event_models")


def register_model(cls: type[_StreamingModel]) -> type[_StreamingModel]:
    """Add an event model class (its ``name``, ``from_config``, ``log_contrast``,
    ``sampling_step``, ``log_signal_of`` and kernels) to :data:`MODELS`; for the
    workflow also add the name to the schema's ``events.model`` enum."""
    if not cls.name:
        raise ValueError(f"{cls.__name__}: an event model needs a name")
    return add(MODELS, cls.name, cls, "event model")


def model_class(name: str) -> type[_StreamingModel]:
    if name not in MODELS:
        raise ConfigError(f"events.model: unknown model '{name}' (choose from {', '.join(MODELS)})")
    return MODELS[name]


def log_contrast(settings: EventSettings, theta_on=None, theta_off=None):
    """The event model's contrast in log units: (theta_on, theta_off, eps), the
    log(L + eps) steps that fire an ON / OFF event, L linear luminance in [0, 1].

    ``theta_on`` / ``theta_off``: the model's own thresholds (scalars or (H, W)
    maps as events.h5 stores them; default: the config's nominal ones).
    Ideal model: as given, eps = ``log_eps``. DVS-Voltmeter: its drift
    k1 (dL/dt) / (L + k2) integrates to a voltage k1 log(L * scale + k2), so a
    voltage threshold theta is the step theta / k1 of log(L + k2 / scale);
    noise and leak are not part of it.
    """
    cfg = require(settings, EventSettings, "log_contrast")
    on = np.asarray(cfg.theta_on if theta_on is None else theta_on, np.float64)
    off = np.asarray(cfg.theta_off if theta_off is None else theta_off, np.float64)
    return model_class(cfg.model).log_contrast(cfg, on, off)


register_model(IdealModel)
register_model(VoltmeterModel)
MODELS.plugins(register_model, lambda cls: cls.name)
