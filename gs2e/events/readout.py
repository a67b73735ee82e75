"""The sensor around the pixel model: photoreceptor bandwidth, hot pixels and
a readout of finite throughput. Each is off unless the ``events`` section or
the sensor preset sets it; off, the chain hands the model's events on as they
are (no copy, no cost).

Photoreceptor bandwidth (``photoreceptor_cutoff_hz``, ``photoreceptor_dark_fraction``)
    A first-order low-pass of each pixel's linear luminance L whose cutoff
    falls with the light, f_c(L) = cutoff_hz (L + d) / (1 + d), d the dark
    fraction: a photoreceptor's bandwidth grows with its photocurrent
    (Lichtsteiner et al., JSSC 2008; v2e's intensity-dependent cutoff). Over
    a sample interval the input is the model's own linear interpolation and
    the cutoff that of the interval's mean input, for which the filter's
    response is exact: y1 = x1 + (y0 - x0) e^{-h} - (x1 - x0) (1 - e^{-h}) / h,
    h = 2 pi f_c dt. Dark pixels lag and smear their events in time.

Hot pixels (``hot_pixel_fraction``, ``hot_pixel_rate_hz``, ``hot_pixel_on_fraction``)
    A seeded random set of pixels firing Poisson events at ``hot_pixel_rate_hz``
    each, ON with probability ``hot_pixel_on_fraction``, whatever the scene.
    Drawn per block of :data:`HOT_BLOCK_US` from a stream keyed by (seed,
    block, pixel): the same events however the simulation is batched.

Readout (``readout_rate_meps``, ``readout_latency_us``, ``readout_jitter_us``, ``readout_queue_events``)
    One first-in-first-out arbiter serving ``readout_rate_meps`` million events
    per second: an event leaves at d_i = max(t_i, d_{i-1}) + 1 / rate and is
    timestamped d_i + latency + jitter (jitter uniform in +-jitter_us, keyed
    by the event's index; never before t_i); an event arriving while
    ``readout_queue_events`` events wait is dropped (a burst larger than the
    readout can carry loses its excess, as IEBCS's and Prophesee's readouts
    do). Timestamps stay sorted (the stream is re-sorted within the jitter).

:class:`SensorChain` wraps a model (:mod:`gs2e.events.models`) with the three,
for :func:`gs2e.events.simulate.simulate_to_folder` and in-memory use alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from gs2e.common.errors import InputError
from gs2e.common.settings import require
from gs2e.events import _kernels as K
from gs2e.events.models import Events, TileBatch
from gs2e.events.sensors import READOUT_KEYS
from gs2e.events.settings import EventSettings

HOT_BLOCK_US = 100_000
_SALT_HOT_PICK, _SALT_HOT_EVENTS, _SALT_JITTER = 0x4807, 0x4808, 0x4809



@dataclass(frozen=True)
class ReadoutSettings:
    """The resolved keys of :data:`READOUT_KEYS` (None: that part is off)."""

    photoreceptor_cutoff_hz: float | None = None
    photoreceptor_dark_fraction: float = 0.1
    hot_pixel_fraction: float = 0.0
    hot_pixel_rate_hz: float = 0.0
    hot_pixel_on_fraction: float = 0.5
    readout_rate_meps: float | None = None
    readout_latency_us: float = 0.0
    readout_jitter_us: float = 0.0
    readout_queue_events: int = 1024

    @property
    def lowpass_on(self) -> bool:
        return self.photoreceptor_cutoff_hz is not None

    @property
    def hot_on(self) -> bool:
        return self.hot_pixel_fraction > 0 and self.hot_pixel_rate_hz > 0

    @property
    def readout_on(self) -> bool:
        return self.readout_rate_meps is not None

    @property
    def any_on(self) -> bool:
        return self.lowpass_on or self.hot_on or self.readout_on


def resolve_readout(settings: EventSettings) -> tuple[ReadoutSettings, dict]:
    """(ReadoutSettings, sources): an explicit config value wins, then the
    sensor preset's (``Sensor.extra['readout']``), then off / the default."""
    from gs2e.events.sensors import get_sensor

    cfg = require(settings, EventSettings, "resolve_readout")
    sensor = get_sensor(cfg)
    preset = (sensor.extra.get("readout") or {}) if sensor is not None else {}
    values, sources = {}, {}
    for key, default in READOUT_KEYS.items():
        v = getattr(cfg, key)
        if v is not None:
            values[key], sources[key] = v, "config"
        elif key in preset:
            values[key], sources[key] = preset[key].value, f"sensor {sensor.name}: {preset[key].source}"
        else:
            values[key], sources[key] = default, "default (off)" if default in (None, 0.0) else "default"
    values["readout_queue_events"] = int(values["readout_queue_events"])
    return ReadoutSettings(**values), sources


# ---------------------------------------------------------------- photoreceptor
def lowpass_step(y0: np.ndarray, x0: np.ndarray, x1: np.ndarray, dt_us: float, cutoff_hz: float,
                 dark_fraction: float) -> np.ndarray:
    """One interval of the photoreceptor low-pass: the output at its end.

    ``y0`` the output and ``x0`` the input at the start, ``x1`` the input at
    the end (linear luminance, any shape), ``dt_us`` > 0 the interval."""
    xm = 0.5 * (x0 + x1)
    fc = cutoff_hz * (np.maximum(xm, 0.0) + dark_fraction) / (1.0 + dark_fraction)
    h = (2.0 * math.pi * 1e-6 * float(dt_us)) * fc
    e = np.exp(-h)
    # (1 - e^-h) / h, its limit 1 as h -> 0 (expm1 keeps digits at small h)
    g = np.where(h > 1e-12, -np.expm1(-h) / np.where(h > 1e-12, h, 1.0), 1.0)
    return x1 + (y0 - x0) * e - (x1 - x0) * g


class Photoreceptor:
    """The low-pass as a stream: ``start(t, frame)`` then ``filter(ts, frames)``
    (whole frames) or ``filter_tiles(batch, tile, W)`` (tile batches)."""

    def __init__(self, cutoff_hz: float, dark_fraction: float):
        self.cutoff_hz, self.dark = float(cutoff_hz), float(dark_fraction)
        self.y = self.x = None
        self.t_us = None  # of the last whole frame (tile intervals carry their own times)

    def start(self, t_us: int, frame: np.ndarray) -> np.ndarray:
        self.x = np.asarray(frame, np.float64).copy()
        self.y = self.x.copy()  # at rest: the output equals the input
        self.t_us = int(t_us)
        return frame

    def filter(self, ts_us, frames) -> np.ndarray:
        out = np.empty_like(frames)
        for i, (t, f) in enumerate(zip(ts_us, frames)):
            x1 = np.asarray(f, np.float64)
            self.y = lowpass_step(self.y, self.x, x1, int(t) - self.t_us, self.cutoff_hz, self.dark)
            self.x, out[i] = x1, self.y
            self.t_us = int(t)
        return out

    def filter_tiles(self, b: TileBatch, tile: int, width: int) -> TileBatch:
        n_tx = -(-width // tile)
        lum = np.empty_like(b.lum)
        H, W = self.x.shape
        for s, tid in enumerate(b.tiles):
            y0, x0 = (int(tid) // n_tx) * tile, (int(tid) % n_tx) * tile
            h, w = min(tile, H - y0), min(tile, W - x0)
            ys, xs = slice(y0, y0 + h), slice(x0, x0 + w)
            for k in range(b.offsets[s], b.offsets[s + 1]):
                x1 = np.asarray(b.lum[k, :h, :w], np.float64)
                dt = int(b.t1_us[k] - b.t0_us[k])
                self.y[ys, xs] = lowpass_step(self.y[ys, xs], self.x[ys, xs], x1, dt,
                                              self.cutoff_hz, self.dark)
                self.x[ys, xs] = x1
                lum[k] = b.lum[k]
                lum[k, :h, :w] = self.y[ys, xs]
        return TileBatch(b.tiles, b.offsets, b.t0_us, b.t1_us, b.key_idx, lum)


# ---------------------------------------------------------------- hot pixels
def hot_pixels(shape: tuple[int, int], fraction: float, seed: int) -> np.ndarray:
    """Sorted flat indices (y * W + x) of the hot pixels: round(fraction H W)
    of them, drawn without replacement from the seed."""
    H, W = shape
    n = int(round(fraction * H * W))
    rng = np.random.default_rng([int(seed), _SALT_HOT_PICK])
    return np.sort(rng.choice(H * W, size=min(n, H * W), replace=False)).astype(np.int64)


@njit(cache=True)
def _hot_block(seed, block, t0, t1, pixels, rate_per_us, on_fraction):
    """Poisson events of each hot pixel over [t0, t1) (one block), unsorted."""
    cap = 16
    t = np.empty(cap, np.int64)
    pix = np.empty(cap, np.int64)
    pol = np.empty(cap, np.uint8)
    n = 0
    for j in range(pixels.shape[0]):
        st = K.stream_state(seed, block, pixels[j], _SALT_HOT_EVENTS)
        tt = float(t0)
        while True:
            st, u = K.uniform_open(st)
            tt += -math.log(u) / rate_per_us
            if tt >= t1:
                break
            st, v = K.uniform_open(st)
            if n == cap:
                cap *= 2
                t2, p2, o2 = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.uint8)
                t2[:n], p2[:n], o2[:n] = t[:n], pix[:n], pol[:n]
                t, pix, pol = t2, p2, o2
            t[n], pix[n], pol[n] = np.int64(tt), pixels[j], np.uint8(1 if v < on_fraction else 0)
            n += 1
    return t[:n], pix[:n], pol[:n]


def hot_pixel_events(pixels: np.ndarray, width: int, rate_hz: float, on_fraction: float,
                     t0_us: int, t1_us: int, seed: int) -> Events:
    """The hot pixels' events over [t0_us, t1_us), time-sorted; identical
    however [t0, t1) is cut into calls (blocks of :data:`HOT_BLOCK_US`)."""
    if t1_us <= t0_us or len(pixels) == 0 or rate_hz <= 0:
        return Events.empty()
    parts = []
    for blk in range(t0_us // HOT_BLOCK_US, -(-t1_us // HOT_BLOCK_US)):
        b0, b1 = blk * HOT_BLOCK_US, (blk + 1) * HOT_BLOCK_US
        t, pix, pol = _hot_block(int(seed), int(blk), b0, b1, pixels, rate_hz * 1e-6, float(on_fraction))
        keep = (t >= t0_us) & (t < t1_us)
        parts.append((t[keep], pix[keep], pol[keep]))
    t = np.concatenate([p[0] for p in parts])
    pix = np.concatenate([p[1] for p in parts])
    pol = np.concatenate([p[2] for p in parts])
    order = np.lexsort((pix, t))
    t, pix, pol = t[order], pix[order], pol[order]
    return Events(t, (pix % width).astype(np.uint16), (pix // width).astype(np.uint16), pol)


def merge_events(a: Events, b: Events) -> Events:
    """Two time-sorted streams as one (stable: ``a`` first at equal times)."""
    if len(b) == 0:
        return a
    if len(a) == 0:
        return b
    t = np.concatenate([a.t, b.t])
    order = np.argsort(t, kind="stable")
    return Events(t[order], np.concatenate([a.x, b.x])[order], np.concatenate([a.y, b.y])[order],
                  np.concatenate([a.p, b.p])[order])


# ---------------------------------------------------------------- readout
@njit(cache=True)
def _readout(t_in, first_index, seed, service_us, latency_us, jitter_us, queue, ring, state):
    """FIFO arbiter over time-sorted arrivals ``t_in``; ``state`` =
    [last departure, ring head, ring count] carried between calls, ``ring``
    the departures of the last accepted events (capacity queue + 1).
    Returns (t_out float64, keep bool)."""
    n = t_in.shape[0]
    t_out = np.empty(n, np.float64)
    keep = np.zeros(n, np.bool_)
    d_prev, head, count = state[0], int(state[1]), int(state[2])
    cap = ring.shape[0]
    for i in range(n):
        ti = float(t_in[i])
        # events still waiting (or being served) at ti: accepted, departing after ti
        while count > 0 and ring[(head - count) % cap] <= ti:
            count -= 1
        if count > queue:
            continue  # dropped
        d = max(ti, d_prev) + service_us
        d_prev = d
        ring[head % cap] = d
        head = (head + 1) % cap
        count = min(count + 1, cap)
        j = 0.0
        if jitter_us > 0:
            st = K.stream_state(seed, first_index + i, 0, _SALT_JITTER)
            st, u = K.uniform_open(st)
            j = (2.0 * u - 1.0) * jitter_us
        t_out[i] = max(ti, d + latency_us + j)
        keep[i] = True
    state[0], state[1], state[2] = d_prev, head, count
    return t_out, keep


class Readout:
    """The arbiter as a stream: ``process(events, horizon)`` returns the
    events whose output time is final (before any later event's), ``flush()``
    the rest. ``dropped`` counts the events lost to a full queue."""

    def __init__(self, rate_meps: float, latency_us: float, jitter_us: float, queue_events: int,
                 seed: int):
        self.service_us = 1.0 / float(rate_meps)
        self.latency_us, self.jitter_us = float(latency_us), float(jitter_us)
        self.queue = int(queue_events)
        self.seed = int(seed)
        self.ring = np.zeros(self.queue + 2, np.float64)
        self.state = np.array([-np.inf, 0.0, 0.0])
        self.n_in = self.dropped = 0
        self._carry = Events.empty()

    def _out(self, ev: Events) -> Events:
        t_out, keep = _readout(ev.t, self.n_in, self.seed, self.service_us, self.latency_us,
                               self.jitter_us, self.queue, self.ring, self.state)
        self.n_in += len(ev)
        self.dropped += int(len(ev) - keep.sum())
        return Events(np.floor(t_out[keep]).astype(np.int64), ev.x[keep], ev.y[keep], ev.p[keep])

    def process(self, ev: Events, horizon_us: int | None) -> Events:
        out = merge_events(self._carry, self._out(ev)) if len(ev) else self._carry
        out = _sorted(out)
        if horizon_us is None:
            self._carry = Events.empty()
            return out
        # a later arrival (t >= horizon) leaves at >= horizon + latency - jitter
        cut = int(np.searchsorted(out.t, horizon_us + self.latency_us - self.jitter_us, side="left"))
        self._carry = Events(out.t[cut:], out.x[cut:], out.y[cut:], out.p[cut:])
        return Events(out.t[:cut], out.x[:cut], out.y[:cut], out.p[:cut])

    def flush(self) -> Events:
        return self.process(Events.empty(), None)


def _sorted(ev: Events) -> Events:
    if len(ev) < 2 or np.all(ev.t[1:] >= ev.t[:-1]):
        return ev
    o = np.argsort(ev.t, kind="stable")
    return Events(ev.t[o], ev.x[o], ev.y[o], ev.p[o])


# ---------------------------------------------------------------- the chain
class SensorChain:
    """A model with the photoreceptor before it and hot pixels and the
    readout after it; the model's streaming interface (``start``,
    ``process_batch``, ``process_tiles``, ``flush``, ``horizon_us``)."""

    def __init__(self, model, readout: ReadoutSettings, seed: int):
        self.model, self.cfg = model, readout
        self.shape = model.shape
        self.photo = (Photoreceptor(readout.photoreceptor_cutoff_hz, readout.photoreceptor_dark_fraction)
                      if readout.lowpass_on else None)
        self.hot = hot_pixels(self.shape, readout.hot_pixel_fraction, seed) if readout.hot_on else None
        self.readout = (Readout(readout.readout_rate_meps, readout.readout_latency_us,
                                readout.readout_jitter_us, readout.readout_queue_events, seed)
                        if readout.readout_on else None)
        self.seed = int(seed)
        self._hot_t = self._t_last = None  # hot-pixel events are out up to _hot_t

    @property
    def horizon_us(self):
        """No event released later is before this time."""
        h = self.model.horizon_us
        if h is None or self.readout is None:
            return h
        return int(math.floor(h + self.readout.latency_us - self.readout.jitter_us))

    def start(self, t_us: int, frame: np.ndarray) -> None:
        if self.photo is not None:
            self.photo.start(int(t_us), frame)
        self._hot_t = self._t_last = int(t_us)
        self.model.start(t_us, frame)

    def _after(self, ev: Events, horizon: int | None) -> Events:
        if self.hot is not None:
            end = horizon if horizon is not None else max(self._hot_t, int(self._t_last) + 1)
            if end > self._hot_t:
                ev = merge_events(ev, hot_pixel_events(
                    self.hot, self.shape[1], self.cfg.hot_pixel_rate_hz, self.cfg.hot_pixel_on_fraction,
                    self._hot_t, end, self.seed))
                self._hot_t = end
        if self.readout is not None:
            ev = self.readout.process(ev, horizon)
        return ev

    def _started(self) -> None:
        if self._hot_t is None:
            raise InputError(f"{self.model.source}: start() the sensor chain with a first frame")

    def process_batch(self, ts_us, frames) -> Events:
        if not self.cfg.any_on:
            return self.model.process_batch(ts_us, frames)
        self._started()
        if len(ts_us) == 0:
            return Events.empty()
        if self.photo is not None:  # bad frames filter to bad frames, which the model rejects
            frames = self.photo.filter(ts_us, np.asarray(frames))
        ev = self.model.process_batch(ts_us, frames)
        self._t_last = self.model.t_prev
        return self._after(ev, self.model.horizon_us)

    def process_tiles(self, b: TileBatch) -> Events:
        if not self.cfg.any_on:
            return self.model.process_tiles(b)
        self._started()
        if len(b) == 0:
            return self.model.process_tiles(b)
        if self.photo is not None:
            from gs2e.events.models import TILE

            b = self.photo.filter_tiles(b, TILE, self.shape[1])
        self._t_last = max(self._t_last, int(np.max(b.t1_us)))
        return self._after(self.model.process_tiles(b), self.model.horizon_us)

    def flush(self) -> Events:
        if not self.cfg.any_on:
            return self.model.flush()
        self._started()
        return self._after(self.model.flush(), None)

    def simulate(self, ts_us, frames) -> Events:
        """All events of an in-memory frame sequence."""
        ts_us = np.asarray(ts_us, np.int64)
        self.start(int(ts_us[0]), np.asarray(frames[0]))
        return Events.concat([self.process_batch(ts_us[1:], frames[1:]), self.flush()])

    def describe(self) -> dict:
        return {"photoreceptor_cutoff_hz": self.cfg.photoreceptor_cutoff_hz,
                "hot_pixels": 0 if self.hot is None else int(len(self.hot)),
                "readout_dropped": 0 if self.readout is None else int(self.readout.dropped)}
