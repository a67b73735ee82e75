"""Compiled (numba) kernels of the event models.

Everything per pixel is computed in float64; times are float64 microseconds
internally and int64 microseconds on output.

Random numbers: a counter-based stream per (seed, frame index, pixel, purpose)
(SplitMix64 seeded by a hash of the key), so the events do not depend on the
number of threads or on the order in which rows are processed: same seed, same
bytes.

Work comes as a batch of TILE INTERVALS (:class:`TileIntervals`): per slot,
one tile (``tile`` x ``tile`` pixels) and its consecutive intervals; a whole
frame is one interval of every tile. Slots run in parallel (``prange``, one
parallel region per batch; pixels are independent, so a thread runs its tile's
pixels through all of the slot's intervals). Each slot writes its events into
its own slice of the buffers (:class:`EventSlots`: ``cap`` events per slot)
and counts them per interval. A slot that overflows its slice reports how many
it needed; the caller re-runs the batch with larger slices (state is read from
``state_in`` and written to ``state_out`` (:class:`PixelState`), so a re-run
sees the same input state and produces the same events), then commits the
new state with :func:`commit_tiles` and collects the events with
:func:`gather_tiles`.

The arguments are grouped in named tuples (numba passes them as structs):
what the batch is, the image grid, the model's parameters, its state and the
output slots.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit, prange


class TileIntervals(NamedTuple):
    """A batch of tile intervals, slot by slot."""

    tiles: np.ndarray    # (m,) int64 tile of each slot (row-major tile number)
    offsets: np.ndarray  # (m + 1,) int64: slot s holds intervals offsets[s] .. offsets[s + 1] - 1
    t0_us: np.ndarray    # (n,) int64 start of each interval (absolute us)
    t1_us: np.ndarray    # (n,) int64 end of each interval
    key_idx: np.ndarray  # (n,) int64 index of the interval's end sample in its tile's sequence
    lum: np.ndarray      # (n, tile, tile) linear luminance in [0, 1] at t1 of each interval


class Grid(NamedTuple):
    """The image: ``height`` x ``width`` pixels in tiles of ``tile`` x ``tile``."""

    height: int
    width: int
    tile: int


class PixelState(NamedTuple):
    """(H, W) float64 state of a model per pixel: the luminance of its last
    sample, then the model's own two arrays (voltmeter: residual voltage and
    ready time; ideal: reference level and last event time)."""

    prev: np.ndarray
    a: np.ndarray
    b: np.ndarray


class EventSlots(NamedTuple):
    """Output buffers: slot s owns entries [s cap, (s + 1) cap); ``counts[i]``
    receives the number of events of interval i (a slot total above ``cap``
    means overflow: nothing beyond it is written)."""

    cap: int
    t: np.ndarray       # float64 us relative to the start of the event's interval
    x: np.ndarray       # int32 column
    y: np.ndarray       # int32 row
    p: np.ndarray       # int8 polarity, +1 / -1
    counts: np.ndarray  # (n,) int64


class VoltmeterParams(NamedTuple):
    """DVS-Voltmeter's parameters (see :func:`voltmeter_tiles`)."""

    intensity_scale: float  # linear luminance -> the preset's intensity unit
    seed: int
    k: np.ndarray           # (6,) float64 k1..k6 in the preset's units
    time_unit_us: float     # the preset's time unit
    theta_on: np.ndarray    # (H, W) float64 barrier heights (normalised voltage, > 0)
    theta_off: np.ndarray
    refractory_us: float
    max_events_px: int      # per pixel and interval
    two_barrier: bool       # the exact exit law instead of DVS-Voltmeter's


class IdealParams(NamedTuple):
    """The ideal model's parameters (see :func:`ideal_tiles`)."""

    log_eps: float
    theta_on: np.ndarray    # (H, W) float64 log-intensity steps (> 0)
    theta_off: np.ndarray
    refractory_us: float
    max_events_px: int


class NoiseParams(NamedTuple):
    """Noise parameters (see :func:`noise_tiles`)."""

    seed: int
    leak_rate_hz: float
    shot_rate_hz: float
    shot_on_fraction: float
    block_us: int           # :func:`noise_block_us`
    leak_light_rate_hz: float = 0.0  # leak per unit of linear luminance (grows with the light)
    lum_max: float = 1.0    # bound of the luminance the rates follow (the light's largest scale)

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_K_FRAME = np.uint64(0xD1B54A32D192ED03)
_K_SALT = np.uint64(0x8CB92BA72F3D8DD7)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53
_TWO_PI = 2.0 * math.pi

# Purposes of random streams (salts), so signal and noise never share draws.
SALT_SIGNAL = 1
SALT_NOISE = 2


@njit(inline="always", cache=True)
def _mix64(z):
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@njit(inline="always", cache=True)
def frame_key(seed, frame_idx, salt):
    """Key of the streams of one frame interval (hash of seed, frame, salt)."""
    s = _mix64(np.uint64(seed) ^ (np.uint64(salt) * _K_SALT))
    return _mix64(s ^ (np.uint64(frame_idx) * _K_FRAME))


@njit(inline="always", cache=True)
def pixel_state(key, pixel):
    """Initial SplitMix64 state of one pixel's stream within a frame key."""
    return _mix64(key ^ (np.uint64(pixel) * _GOLDEN))


@njit(cache=True)
def stream_state(seed, frame_idx, pixel, salt):
    """Initial SplitMix64 state of the stream keyed by (seed, frame, pixel, salt)."""
    return pixel_state(frame_key(seed, frame_idx, salt), pixel)


@njit(inline="always", cache=True)
def _next(state):
    state = state + _GOLDEN
    return state, _mix64(state)


@njit(inline="always", cache=True)
def uniform_open(state):
    """Uniform in (0, 1) (never 0 or 1), 53-bit resolution."""
    state, z = _next(state)
    return state, (float(z >> _S11) + 0.5) * _INV53


def _ziggurat_tables(n=256, r=3.6541528853610088, v=0.00492867323399):
    """Marsaglia-Tsang ziggurat tables for the standard normal, 52-bit version
    (layer i spans x in [0, w_i 2^52]; fast acceptance if |draw| < k_i)."""
    m = 2.0 ** 52
    ki = np.zeros(n, np.uint64)
    wi = np.zeros(n)
    fi = np.zeros(n)
    dn = tn = r
    q = v / math.exp(-0.5 * dn * dn)
    ki[0] = np.uint64((dn / q) * m)
    wi[0] = q / m
    wi[n - 1] = dn / m
    fi[0] = 1.0
    fi[n - 1] = math.exp(-0.5 * dn * dn)
    for i in range(n - 2, 0, -1):
        dn = math.sqrt(-2.0 * math.log(v / dn + math.exp(-0.5 * dn * dn)))
        ki[i + 1] = np.uint64((dn / tn) * m)
        tn = dn
        fi[i] = math.exp(-0.5 * dn * dn)
        wi[i] = dn / m
    return ki, wi, fi


_ZK, _ZW, _ZF = _ziggurat_tables()
_ZR = 3.6541528853610088
_MASK52 = np.uint64((1 << 52) - 1)
_S8 = np.uint64(8)
_S9 = np.uint64(9)
_ONE = np.uint64(1)
_B255 = np.uint64(255)


@njit(inline="always", cache=True)
def normal_zig(state):
    """Standard normal by the ziggurat method: one 64-bit draw and a table
    look-up ~99 % of the time (inlined); the rest in :func:`_normal_zig_slow`."""
    state, r = _next(state)
    idx = np.int64(r & _B255)
    rabs = (r >> _S9) & _MASK52
    if rabs < _ZK[idx]:
        x = float(rabs) * _ZW[idx]
        return state, (-x if ((r >> _S8) & _ONE) == _ONE else x)
    return _normal_zig_slow(state, r)


@njit(cache=True)
def _normal_zig_slow(state, r):
    """Ziggurat wedges and tail, starting from the rejected draw ``r``."""
    first = True
    while True:
        if not first:
            state, r = _next(state)
        first = False
        idx = np.int64(r & _B255)
        neg = ((r >> _S8) & _ONE) == _ONE
        rabs = (r >> _S9) & _MASK52
        x = float(rabs) * _ZW[idx]
        if neg:
            x = -x
        if rabs < _ZK[idx]:
            return state, x
        if idx == 0:
            # tail beyond r (Marsaglia's method)
            while True:
                state, u1 = uniform_open(state)
                state, u2 = uniform_open(state)
                xx = -math.log(u1) / _ZR
                yy = -math.log(u2)
                if yy + yy > xx * xx:
                    break
            return state, (-(_ZR + xx) if neg else _ZR + xx)
        state, u = uniform_open(state)
        if _ZF[idx] + u * (_ZF[idx - 1] - _ZF[idx]) < math.exp(-0.5 * x * x):
            return state, x


@njit(cache=True)
def p_on_two_barrier(mu, sigma, a, b):
    """Probability that drifted Brownian motion (drift ``mu``, diffusion
    ``sigma``) started between barriers leaves through the upper one, which is
    ``a`` above, before the lower one, ``b`` below (a, b > 0).

    p = (exp(z b) - 1) / (exp(z b) - exp(-z a)),  z = 2 mu / sigma^2,
    evaluated with expm1 in a form that never overflows; the mu -> 0 limit is
    b / (a + b) (not 1/2 unless the residual is 0).
    """
    if sigma <= 0.0:
        if mu > 0.0:
            return 1.0
        if mu < 0.0:
            return 0.0
        return b / (a + b)
    z = 2.0 * mu / (sigma * sigma)
    w = a + b
    if abs(z) * w < 1e-12:
        return b / w
    if z > 0.0:
        # multiply numerator and denominator by exp(-z b)
        return math.expm1(-z * b) / math.expm1(-z * w)
    # z < 0: multiply by exp(z a)
    return math.exp(z * a) * (math.expm1(z * b) / math.expm1(z * w))


@njit(cache=True)
def first_passage_time(nu2, u, eps, c, sigma):
    """First-passage time of Brownian motion with drift magnitude ``c`` >= 0
    towards a barrier at distance ``eps`` > 0, diffusion ``sigma``.

    ``nu2`` is a chi-square(1) variate (a squared standard normal) and ``u`` a
    uniform in (0, 1). c > 0: inverse Gaussian IG(mean eps/c, shape
    (eps/sigma)^2) by Michael-Schucany-Haas, written without cancellation
    (x = 4 m / (sqrt(q) + sqrt(q + 4))^2, q = m nu2 / shape). c == 0: Levy with
    scale (eps/sigma)^2, i.e. shape / nu2. Drift away from the barrier is
    handled by the caller passing |drift| (the law conditional on hitting, see
    gs2e/events/models.py). Returns +inf when the barrier is never reached.
    """
    if sigma <= 0.0:
        if c > 0.0:
            return eps / c
        return math.inf
    lam = (eps / sigma) ** 2
    if c <= 0.0:
        if nu2 <= 0.0:
            return math.inf
        return lam / nu2
    m = eps / c
    q = m * nu2 / lam
    x = 4.0 * m / (math.sqrt(q) + math.sqrt(q + 4.0)) ** 2
    if u * (m + x) <= m:
        return x
    return (m / x) * m


@njit(cache=True)
def poisson_small(state, lam):
    """Poisson(lam) by inversion (meant for small lam, as noise per frame)."""
    state, u = uniform_open(state)
    k = 0
    p = math.exp(-lam)
    s = p
    while u > s and k < 100000:
        k += 1
        p *= lam / k
        s += p
        if p == 0.0:
            break
    return state, k


@njit(cache=True)
def _n_images(var, w):
    """Image terms per side needed for series with exponents ~ -k^2 w^2 / var."""
    return 3 + int(math.sqrt(max(var, 0.0)) / w * 6.0)


@njit(cache=True)
def bridge_stay_probability(x, y, lo, hi, var):
    """P(a Brownian bridge from x to y with variance ``var`` (sigma^2 s) stays
    in (lo, hi)), by the method of images:
    sum_k exp(-2 k w (y - x + k w) / var) - exp(-2 (k w - A)(k w - B) / var),
    w = hi - lo, A = hi - x, B = hi - y."""
    w = hi - lo
    A = hi - x
    B = hi - y
    dl = y - x
    K = _n_images(var, w)
    p = 0.0
    for k in range(-K, K + 1):
        kw = k * w
        p += math.exp(-2.0 * kw * (dl + kw) / var) - math.exp(-2.0 * (kw - A) * (kw - B) / var)
    return min(max(p, 0.0), 1.0)


@njit(cache=True)
def two_barrier_ratio(a, w, var_tau):
    """g_two(tau) / g_single(tau): density of exiting through a barrier at
    distance a at time tau with the other barrier at distance w - a, relative
    to the single-barrier first-passage density (drift-free; ``var_tau`` =
    sigma^2 tau): sum_k (1 + 2 k w / a) exp(-2 k w (a + k w) / var_tau)."""
    K = _n_images(var_tau, w)
    r = 0.0
    for k in range(-K, K + 1):
        kw = k * w
        r += (1.0 + 2.0 * kw / a) * math.exp(-2.0 * kw * (a + kw) / var_tau)
    return min(max(r, 0.0), 1.0)


@njit(cache=True)
def bridge_crossing_time(s, eps, d, nu2, u, sg):
    """Time (in [0, s]) at which a bridge that moves towards a barrier at
    distance eps and ends d short of it (d < 0: beyond) first reaches it,
    given that it does: tau = s U / (s + U) with U ~ IG(eps s / |d|,
    eps^2 / sigma^2) (time change of the bridge). nu2: chi-square(1), u:
    uniform. Written with two divisions."""
    ad = abs(d)
    if ad > 0.0 and sg > 0.0:
        r1e = 1.0 / (ad * eps)
        m = eps * eps * s * r1e
        q = s * nu2 * sg * sg * r1e
        S = (math.sqrt(q) + math.sqrt(q + 4.0)) ** 2
        if u * (S + 4.0) <= S:       # keep x = 4 m / S
            tau = 4.0 * s * m / (s * S + 4.0 * m)
        else:                        # take m^2 / x = m S / 4
            tau = s * m * S / (4.0 * s + m * S)
        if not (tau >= 0.0 and tau <= s):
            tau = s  # m or S overflowed: the crossing is at the end
        return tau
    U = first_passage_time(nu2, u, eps, ad / s, sg)
    return s if not math.isfinite(U) else s * (U / (s + U))


@njit(cache=True)
def slot_order(n):
    """Slots in golden-ratio order, so that the equal contiguous chunks of
    iterations each thread gets cover tiles from the whole image (event load
    is uneven across the image). Only the processing order changes, not the
    output."""
    key = np.empty(n)
    for i in range(n):
        key[i] = (i * 0.6180339887498949) % 1.0
    return np.argsort(key)


@njit(inline="always", cache=True)
def tile_box(t, tiles_x, tile, H, W):
    """Pixel rows [y0, y1) and columns [x0, x1) of tile t."""
    ty = t // tiles_x
    tx = t - ty * tiles_x
    y0 = ty * tile
    x0 = tx * tile
    return y0, min(H, y0 + tile), x0, min(W, x0 + tile)


@njit(cache=True)
def _voltmeter_slot(sl, batch, grid, params, state_in, state_out, slots):
    """Slot ``sl`` of :func:`voltmeter_tiles`; returns its number of capped
    pixel-intervals."""
    # fields by name: a field added to a tuple cannot shift the others
    btiles, boff, t0_us, t1_us, lum = batch.tiles, batch.offsets, batch.t0_us, batch.t1_us, batch.lum
    key_idx = batch.key_idx
    H, W, tile = grid.height, grid.width, grid.tile
    scale, seed, k, tu_us = params.intensity_scale, params.seed, params.k, params.time_unit_us
    th_on, th_off, refractory_us = params.theta_on, params.theta_off, params.refractory_us
    max_events_px, two_barrier = params.max_events_px, params.two_barrier
    prev_in, res_in, ready_in = state_in.prev, state_in.a, state_in.b
    prev_out, res_out, ready_out = state_out.prev, state_out.a, state_out.b
    cap, ev_t, ev_x, ev_y, ev_p, fn = slots.cap, slots.t, slots.x, slots.y, slots.p, slots.counts
    tiles_x = (W + tile - 1) // tile
    k1, k2, k3, k4, k5, k6 = k[0], k[1], k[2], k[3], k[4], k[5]
    capped = 0
    y0, y1, x0, x1 = tile_box(btiles[sl], tiles_x, tile, H, W)
    n = 0
    base = sl * cap
    mu_r = np.empty((tile, tile))
    sg_r = np.empty((tile, tile))
    is_r = np.empty((tile, tile))
    for y in range(y0, y1):
        for x in range(x0, x1):
            prev_out[y, x] = prev_in[y, x]
            res_out[y, x] = res_in[y, x]
            ready_out[y, x] = ready_in[y, x]
    for iv in range(boff[sl], boff[sl + 1]):
        # times within an interval are float64 us RELATIVE to its start
        # (small numbers: exact and shift-invariant at any absolute time)
        t0_rel = 0.0
        t1_rel = float(t1_us[iv] - t0_us[iv])
        inv_dt_m = tu_us / t1_rel
        # drift and diffusion first (a branch-free loop the compiler
        # vectorises), then the sampling loop
        for y in range(y0, y1):
            for x in range(x0, x1):
                a0 = scale * prev_out[y, x]
                a1 = scale * float(lum[iv, y - y0, x - x0])
                lbar = 0.5 * (a0 + a1)
                den = 1.0 / (lbar + k2)
                mu_r[y - y0, x - x0] = k1 * (a1 - a0) * inv_dt_m * den + k4 + k5 * lbar
                sgv = k3 * math.sqrt(max(lbar, 0.0)) * den + k6
                sg_r[y - y0, x - x0] = sgv
                is_r[y - y0, x - x0] = 1.0 / (sgv * sgv)  # inf when sigma = 0
        s_full = 1.0 / inv_dt_m
        sqrt_dt_m = math.sqrt(s_full)
        inv_tu = 1.0 / tu_us
        n_iv0 = n
        key = frame_key(seed, key_idx[iv], SALT_SIGNAL)
        for y in range(y0, y1):
            for x in range(x0, x1):
                prev_out[y, x] = float(lum[iv, y - y0, x - x0])
                mu = mu_r[y - y0, x - x0]
                sg = sg_r[y - y0, x - x0]
                inv_sg2 = is_r[y - y0, x - x0]
                ton = th_on[y, x]
                toff = th_off[y, x]
                v = res_out[y, x]
                t = max(t0_rel, ready_out[y, x])
                st = pixel_state(key, y * W + x)
                cm = abs(mu)
                if sg > 0.0:
                    z2 = 2.0 * mu * inv_sg2
                else:
                    z2 = math.inf if mu > 0 else -math.inf
                npx = 0
                while t < t1_rel:
                    if two_barrier:
                        # exact two-barrier exit of the free drift-diffusion
                        if t == t0_rel:
                            s = s_full
                            sq = sqrt_dt_m
                        else:
                            s = (t1_rel - t) * inv_tu
                            sq = math.sqrt(s)
                        st, zn = normal_zig(st)
                        yend = v + mu * s + sg * sq * zn
                        A = ton - v
                        Bv = ton - yend
                        C = v + toff
                        D = yend + toff
                        if Bv <= 0.0 or D <= 0.0:
                            cross = True
                        else:
                            eu = 2.0 * A * Bv * inv_sg2
                            ed = 2.0 * C * D * inv_sg2
                            if eu > 40.0 * s and ed > 40.0 * s:
                                cross = False  # 1 - P(stay) < 2^-54
                            else:
                                st, u = uniform_open(st)
                                cross = u >= bridge_stay_probability(v, yend, -toff, ton,
                                                                     sg * sg * s)
                        if not cross:
                            v = min(max(yend, -toff * (1.0 - 1e-9)), ton * (1.0 - 1e-9))
                            break
                        # exit side and time given the bridge: propose from the
                        # single-barrier bridge laws (weights = their crossing
                        # probabilities), accept with g_two / g_single
                        p_up = 1.0 if Bv <= 0.0 else math.exp(-2.0 * A * Bv * inv_sg2 / s)
                        p_dn = 1.0 if D <= 0.0 else math.exp(-2.0 * C * D * inv_sg2 / s)
                        wdt = ton + toff
                        for _ in range(1000):
                            st, u = uniform_open(st)
                            on = u * (p_up + p_dn) < p_up
                            eps = A if on else C
                            dd = Bv if on else D
                            st, zu = normal_zig(st)
                            st, u = uniform_open(st)
                            tau = bridge_crossing_time(s, eps, dd, zu * zu, u, sg)
                            var_tau = sg * sg * tau
                            # the ratio is 1 - c e^-E with E = 2 w (w - eps) /
                            # (sigma^2 tau), c <= 2 w / eps + 1: E > 80 makes it
                            # 1 to double precision for eps > 1e-16 w
                            if var_tau <= 0.0 or 2.0 * wdt * (wdt - eps) > 80.0 * var_tau:
                                break
                            st, u = uniform_open(st)
                            if u < two_barrier_ratio(eps, wdt, var_tau):
                                break
                    else:
                        a = ton - v
                        b = toff + v
                        # |z| min(a, b) > 38 decides the polarity exactly at the
                        # 2^-54 resolution of our uniforms: no draw needed then
                        if z2 * b > 38.0:
                            on = True
                        elif z2 * a < -38.0:
                            on = False
                        else:
                            pon = p_on_two_barrier(mu, sg, a, b)
                            st, u = uniform_open(st)
                            on = u < pon
                        eps = a if on else b
                        if t == t0_rel:
                            s = s_full
                            sq = sqrt_dt_m
                        else:
                            s = (t1_rel - t) * inv_tu
                            sq = math.sqrt(s)
                        st, zn = normal_zig(st)
                        yv = cm * s + sg * sq * zn
                        d = eps - yv
                        if d > 0.0:
                            # bridge crossing probability exp(-e), e = 2 eps d / (sigma^2 s);
                            # e > 38 is decided without a draw (and without dividing)
                            e_s = 2.0 * eps * d * inv_sg2
                            if e_s > 38.0 * s:
                                cross = False
                            else:
                                st, u = uniform_open(st)
                                cross = u < math.exp(-e_s / s)
                        else:
                            cross = True
                        if not cross:
                            v = v + yv if on else v - yv
                            # the model fixes the polarity first, so the end point
                            # may lie past the other barrier: keep it in the band
                            lo = -toff * (1.0 - 1e-9)
                            hi = ton * (1.0 - 1e-9)
                            if v < lo:
                                v = lo
                            elif v > hi:
                                v = hi
                            break
                        st, zu = normal_zig(st)
                        st, u = uniform_open(st)
                        tau = bridge_crossing_time(s, eps, d, zu * zu, u, sg)
                    te = t + tau * tu_us
                    if te > t1_rel:
                        te = t1_rel
                    if n < cap:
                        ev_t[base + n] = te
                        ev_x[base + n] = x
                        ev_y[base + n] = y
                        ev_p[base + n] = 1 if on else -1
                    n += 1
                    npx += 1
                    v = 0.0
                    t = te + refractory_us
                    if npx >= max_events_px:
                        capped += 1
                        break
                res_out[y, x] = v
                ready_out[y, x] = t - t1_rel if t > t1_rel else -math.inf
        fn[iv] = n - n_iv0
    return capped


@njit(cache=True, parallel=True, nogil=True)
def voltmeter_tiles(batch, grid, params, state_in, state_out, slots):
    """DVS-Voltmeter pixel model over a batch of tile intervals.

    Parameters
    ----------
    batch : :class:`TileIntervals`. ``key_idx`` keys the random streams
        together with the pixel, so events do not depend on batching or
        threads; ``lum`` rows/columns beyond the image are unused.
    grid : :class:`Grid`.
    params : :class:`VoltmeterParams`. ``two_barrier`` False = DVS-Voltmeter's
        law (below); True = the exact exit of the drift-diffusion from the
        band (-theta_off, theta_on) (see the in-line comments and
        gs2e/events/models.py).
    state_in : :class:`PixelState` (prev, residual voltage, ready time: the
        time (us, relative to the start of the pixel's next interval) until
        which it is held after its last event (refractory; -inf if not held)).
        Read only; the state after the batch goes to ``state_out`` for the
        batch's tiles (a re-run after a buffer overflow sees the same input).
    slots : :class:`EventSlots`, the signal events.
    Returns the number of pixel-intervals whose event count hit ``max_events_px``.

    Given the polarity (two-barrier probability), the voltage moves towards
    the chosen barrier (distance eps) as Brownian motion with drift c = |mu|
    (the law conditional on hitting it, see models.py), so its first passage
    is IG(eps / c, eps^2 / sigma^2). It is simulated exactly per interval by
    its end point: y ~ N(c s, sigma^2 s) over the remaining time s; the path
    crossed if y >= eps, else with the bridge probability
    exp(-2 eps (eps - y) / (sigma^2 s)). Given a crossing, the crossing time of
    the bridge is tau = s U / (s + U) with U the first passage of level eps by
    Brownian motion with drift |eps - y| / s (time change of the bridge), so
    U ~ IG(eps s / |eps - y|, eps^2 / sigma^2). Without a crossing the
    residual is the end point itself.
    """
    # the slot body is a function of its own: numba's parfor passes copy a
    # loop body's IR many times, and the inlined body took minutes to compile
    m = batch.tiles.shape[0]
    capped = np.zeros(m, np.int64)
    order = slot_order(m)
    for si in prange(m):
        sl = order[si]
        capped[sl] = _voltmeter_slot(sl, batch, grid, params, state_in, state_out, slots)
    return capped.sum()


@njit(cache=True, parallel=True, nogil=True)
def ideal_tiles(batch, grid, params, state_in, state_out, slots):
    """Ideal (ESIM-style) model over a batch of tile intervals (arguments as
    :func:`voltmeter_tiles`; ``params`` an :class:`IdealParams`).

    The log intensity G = log(L + log_eps) is taken as linear in time within
    an interval. State (prev, ref, last): ``ref`` is the reference per pixel as
    LINEAR value exp(G_ref) (level of the last crossing), so that the common
    no-crossing case needs no logarithm: a crossing exists iff L + log_eps >=
    ref e^theta_on (or <= ref e^-theta_off); only then are the logs taken.
    ``last``: time (us, relative to the start of the pixel's next interval) of
    its last emitted event (-inf if none). Crossings of G_ref + theta_on (upward) / G_ref -
    theta_off (downward) are timed by linear interpolation of G; an event
    within ``refractory_us`` of the previous emitted one is dropped but the
    reference still advances (as ESIM).
    """
    # fields by name: a field added to a tuple cannot shift the others
    btiles, boff, t0_us, t1_us, lum = batch.tiles, batch.offsets, batch.t0_us, batch.t1_us, batch.lum
    H, W, tile = grid.height, grid.width, grid.tile
    log_eps, th_on, th_off = params.log_eps, params.theta_on, params.theta_off
    refractory_us, max_events_px = params.refractory_us, params.max_events_px
    prev_in, ref_in, last_in = state_in.prev, state_in.a, state_in.b
    prev_out, ref_out, last_out = state_out.prev, state_out.a, state_out.b
    cap, ev_t, ev_x, ev_y, ev_p, fn = slots.cap, slots.t, slots.x, slots.y, slots.p, slots.counts
    m = btiles.shape[0]
    tiles_x = (W + tile - 1) // tile
    capped = np.zeros(m, np.int64)
    order = slot_order(m)
    for si in prange(m):
        sl = order[si]
        y0, y1, x0, x1 = tile_box(btiles[sl], tiles_x, tile, H, W)
        n = 0
        base = sl * cap
        for y in range(y0, y1):
            for x in range(x0, x1):
                prev_out[y, x] = prev_in[y, x]
                ref_out[y, x] = ref_in[y, x]
                last_out[y, x] = last_in[y, x]
        for iv in range(boff[sl], boff[sl + 1]):
            t0_rel = 0.0  # relative times, as in voltmeter_tiles
            dt = float(t1_us[iv] - t0_us[iv])
            n_iv0 = n
            for y in range(y0, y1):
                for x in range(x0, x1):
                    lnew = float(lum[iv, y - y0, x - x0])
                    x1v = lnew + log_eps
                    x0v = prev_out[y, x] + log_eps
                    prev_out[y, x] = lnew
                    rl = ref_out[y, x]
                    ton = th_on[y, x]
                    toff = th_off[y, x]
                    up = x1v > rl
                    # no-crossing certificates without exp/log (e^th >= 1 + th):
                    # most pixels do not move by a threshold in one interval
                    if up:
                        if x1v < rl * (1.0 + ton):
                            last_out[y, x] -= dt
                            continue
                    elif x1v * (1.0 + toff) > rl:
                        last_out[y, x] -= dt
                        continue
                    g0 = math.log(x0v)
                    g1 = math.log(x1v)
                    ref = math.log(rl)
                    last = last_out[y, x]
                    d = g1 - g0
                    th = ton if up else toff
                    npx = 0
                    moved = False
                    if d != 0.0:
                        while (g1 - ref >= th) if up else (ref - g1 >= th):
                            lev = ref + th if up else ref - th
                            te = t0_rel + (lev - g0) / d * dt
                            if te < t0_rel:
                                te = t0_rel
                            ref = lev
                            moved = True
                            if refractory_us <= 0.0 or te - last >= refractory_us:
                                if n < cap:
                                    ev_t[base + n] = te
                                    ev_x[base + n] = x
                                    ev_y[base + n] = y
                                    ev_p[base + n] = 1 if up else -1
                                n += 1
                                last = te
                            npx += 1
                            if npx >= max_events_px:
                                capped[sl] += 1
                                ref = g1
                                break
                    if moved:
                        ref_out[y, x] = math.exp(ref)
                    last_out[y, x] = last - dt  # relative to the next interval's start
            fn[iv] = n - n_iv0
    return capped.sum()


NOISE_TILE_MEAN = 8.0  # mean candidates per (tile, block): sets the block length


def noise_block_us(leak_rate_hz: float, shot_rate_hz: float, tile: int) -> int:
    """Length (us, a power of two) of the time blocks noise is drawn in: about
    :data:`NOISE_TILE_MEAN` candidates per full tile and block at the largest
    per-pixel rate (leak + 2 x shot), between 1 us and 2^26 us (67 s). It
    depends on the rates only, so noise never depends on batching."""
    r_max = float(leak_rate_hz) + 2.0 * float(shot_rate_hz)
    if r_max <= 0.0:
        return 1 << 26
    b = NOISE_TILE_MEAN / (r_max * tile * tile) * 1e6
    return 1 << int(min(26, max(0, math.floor(math.log2(max(b, 1.0))))))


@njit(cache=True)
def _poisson(state, lam):
    """Poisson(lam) by inversion, for any lam (sums of draws of mean <= 500,
    whose exp(-mean) cannot underflow)."""
    parts = max(1, int(math.ceil(lam / 500.0)))
    total = 0
    for _ in range(parts):
        state, k = poisson_small(state, lam / parts)
        total += k
    return state, total


@njit(cache=True)
def _noise_slot(sl, batch, grid, prev, params, slots):
    """Noise events of one slot of :func:`noise_tiles` (counted in a first
    pass, written interval by interval in a second over the same draws)."""
    # fields by name: a field added to a tuple cannot shift the others
    btiles, boff, t0_us, t1_us, lum = batch.tiles, batch.offsets, batch.t0_us, batch.t1_us, batch.lum
    H, W, tile = grid.height, grid.width, grid.tile
    seed, leak_rate_hz, shot_rate_hz = params.seed, params.leak_rate_hz, params.shot_rate_hz
    shot_on_fraction, block_us = params.shot_on_fraction, params.block_us
    leak_light, lum_max = params.leak_light_rate_hz, params.lum_max
    cap, ev_t, ev_x, ev_y, ev_p, fn = slots.cap, slots.t, slots.x, slots.y, slots.p, slots.counts
    base = sl * cap
    tiles_x = (W + tile - 1) // tile
    y0, y1, x0, x1 = tile_box(btiles[sl], tiles_x, tile, H, W)
    w = x1 - x0
    npx = (y1 - y0) * w
    a, b = boff[sl], boff[sl + 1]
    ts, te = t0_us[a], t1_us[b - 1]
    r_max = leak_rate_hz + leak_light * lum_max + 2.0 * shot_rate_hz
    lam = r_max * npx * block_us * 1e-6
    pos = np.zeros(b - a, np.int64)
    for iv in range(a, b):
        fn[iv] = 0
    for write in range(2):
        if write:
            acc = 0
            for j in range(b - a):
                pos[j] = acc
                acc += fn[a + j]
        for blk in range(ts // block_us, (te - 1) // block_us + 1):
            st = stream_state(seed, blk, btiles[sl], SALT_NOISE)
            st, kk = _poisson(st, lam)
            for _ in range(kk):
                st, u = uniform_open(st)
                st, upx = uniform_open(st)
                st, ua = uniform_open(st)
                st, upol = uniform_open(st)
                t = float(blk * block_us) + u * block_us
                if t < ts or t >= te:
                    continue
                lo, hi = a, b - 1  # the interval [t0, t1) holding t
                while lo < hi:
                    mid = (lo + hi) // 2
                    if t < t1_us[mid]:
                        hi = mid
                    else:
                        lo = mid + 1
                iv = lo
                q = min(int(upx * npx), npx - 1)
                y = y0 + q // w
                x = x0 + q % w
                l0 = prev[y, x] if iv == a else float(lum[iv - 1, y - y0, x - x0])
                lval = min(max(0.5 * (l0 + float(lum[iv, y - y0, x - x0])), 0.0), lum_max)
                leak = leak_rate_hz + leak_light * lval
                # thinning: a candidate at the largest rate is kept with rate / r_max
                if ua * r_max >= leak + shot_rate_hz * 2.0 * max(1.0 - lval, 0.0):
                    continue
                if write == 0:
                    fn[iv] += 1
                    continue
                idx = pos[iv - a]
                pos[iv - a] += 1
                if idx < cap:
                    ev_t[base + idx] = t - t0_us[iv]
                    ev_x[base + idx] = x
                    ev_y[base + idx] = y
                    # leak events are ON; shot noise ON with shot_on_fraction
                    ev_p[base + idx] = 1 if (ua * r_max < leak or upol < shot_on_fraction) else -1


@njit(cache=True, parallel=True, nogil=True)
def noise_tiles(batch, grid, prev, params, slots):
    """Noise events over a batch of tile intervals (v2e-like, Poisson per pixel).

    ``batch``, ``grid`` as :func:`voltmeter_tiles`; ``params`` a
    :class:`NoiseParams`; ``slots`` the noise's own :class:`EventSlots`.
    ``prev`` (H, W): luminance of each pixel's sample before the batch (the
    models' state before the batch). Leak events: ON, rate ``leak_rate_hz``
    per pixel. Shot noise: rate ``shot_rate_hz`` per pixel scaled by 2 (1 - L)
    for the pixel's mean linear luminance L over the interval (more in the
    dark; the mean over a uniform histogram is the nominal rate), ON with
    probability ``shot_on_fraction``. Noise events are independent of the
    pixel model's state (they neither reset it nor obey its refractory period,
    as they stand for activity outside the modelled signal path).

    With ``leak_light_rate_hz`` the leak grows with the light, leak +
    leak_light L (parasitic photocurrent; Nozaki and Delbruck, IEEE TED 2017),
    and L runs up to ``lum_max`` (a light brighter than the reference); shot
    noise stops at L >= 1.

    Drawn by thinning: per tile and time block of ``block_us``
    (:func:`noise_block_us`; blocks at multiples of it, keyed by seed, block
    and tile, so neither batching nor threads change a draw), candidates at
    the largest per-pixel rate (leak + 2 x shot), uniform in time and over the
    tile's pixels, each kept with the pixel's rate in its interval over that
    largest rate: the same Poisson process as a draw per pixel and interval,
    at the cost of one draw per tile and block instead of one per pixel and
    interval. Slot s writes to entries [s cap, (s + 1) cap) of the buffers
    (their own, not the signal's), each interval's events after the earlier
    intervals' (``fn`` counts per interval; a count over ``cap`` is reported,
    not written, as in :func:`voltmeter_tiles`).
    """
    for sl in prange(batch.tiles.shape[0]):
        _noise_slot(sl, batch, grid, prev, params, slots)
    return 0


@njit(cache=True, parallel=True, nogil=True)
def commit_tiles(tiles, grid, src, dst):
    """``dst`` = ``src`` (:class:`PixelState`) on the pixels of ``tiles``."""
    H, W, tile = grid.height, grid.width, grid.tile
    src_a, src_b, src_c = src
    dst_a, dst_b, dst_c = dst
    tiles_x = (W + tile - 1) // tile
    for s in prange(tiles.shape[0]):
        y0, y1, x0, x1 = tile_box(tiles[s], tiles_x, tile, H, W)
        for y in range(y0, y1):
            for x in range(x0, x1):
                dst_a[y, x] = src_a[y, x]
                dst_b[y, x] = src_b[y, x]
                dst_c[y, x] = src_c[y, x]


@njit(cache=True, nogil=True)
def gather_tiles(batch, signal, noise, out_t, out_x, out_y, out_p):
    """Collect a batch's events from their slots (``signal``, ``noise``:
    :class:`EventSlots`), interval by interval (its signal events, then its
    noise events, each in emission order), as int64 absolute times ``out_t``:
    the float offset from the interval start rounded to the nearest
    microsecond and clamped to the interval. p becomes 1 (ON) / 0 (OFF).
    Returns the count."""
    boff, t0_us, t1_us = batch.offsets, batch.t0_us, batch.t1_us
    cap, ev_t, ev_x, ev_y, ev_p, fn = signal
    noise_cap, nz_t, nz_x, nz_y, nz_p, fn_noise = noise
    m = boff.shape[0] - 1
    j = 0
    for sl in range(m):
        b_sig = sl * cap
        b_noise = sl * noise_cap
        for iv in range(boff[sl], boff[sl + 1]):
            t0 = t0_us[iv]
            dt = t1_us[iv] - t0
            j = _gather_run(ev_t, ev_x, ev_y, ev_p, b_sig, fn[iv], t0, dt, out_t, out_x, out_y, out_p, j)
            b_sig += fn[iv]
            j = _gather_run(nz_t, nz_x, nz_y, nz_p, b_noise, fn_noise[iv], t0, dt,
                            out_t, out_x, out_y, out_p, j)
            b_noise += fn_noise[iv]
    return j


@njit(inline="always", cache=True)
def _gather_run(ev_t, ev_x, ev_y, ev_p, b0, cnt, t0, dt, out_t, out_x, out_y, out_p, j):
    """Copy ``cnt`` events from ``b0`` of one buffer to ``j`` of the output."""
    for i in range(cnt):
        off = np.int64(math.floor(ev_t[b0 + i] + 0.5))
        off = min(max(off, 0), dt)
        out_t[j] = t0 + off
        out_x[j] = ev_x[b0 + i]
        out_y[j] = ev_y[b0 + i]
        out_p[j] = 1 if ev_p[b0 + i] > 0 else 0
        j += 1
    return j


_SORT_BITS = 11  # radix digit: 2048 buckets, 3 passes for keys below 2^33
_SORT_CHUNKS = 16  # histogram chunks (the result does not depend on them: the sort is stable)


@njit(cache=True, parallel=True, nogil=True)
def sort_events(t, x, y, p, H, W):
    """Events in (time, row, column) order, ties in input order.

    A stable LSD radix sort of the key (t - min t) * H * W + y * W + x
    (int64; only the digits the largest key needs), chunks histogrammed and
    scattered in parallel, the key moved with its index so every pass reads
    sequentially. The order is unique, so it does not depend on the thread
    count. Returns sorted copies of (t, x, y, p)."""
    n = t.shape[0]
    ot = np.empty_like(t)
    ox = np.empty_like(x)
    oy = np.empty_like(y)
    op = np.empty_like(p)
    if n == 0:
        return ot, ox, oy, op
    t_min = t.min()
    key = np.empty(n, np.int64)
    idx = np.empty(n, np.int64)
    for i in prange(n):
        key[i] = (t[i] - t_min) * (H * W) + np.int64(y[i]) * W + np.int64(x[i])
        idx[i] = i
    kmax = key.max()
    key2 = np.empty(n, np.int64)
    idx2 = np.empty(n, np.int64)
    nch = min(_SORT_CHUNKS, n)
    mask = (1 << _SORT_BITS) - 1
    shift = 0
    while (kmax >> shift) > 0:
        hist = np.zeros((nch, mask + 1), np.int64)
        for c in prange(nch):
            for i in range(c * n // nch, (c + 1) * n // nch):
                hist[c, (key[i] >> shift) & mask] += 1
        s = 0  # exclusive prefix: digit-major, chunk-minor (stability)
        for d in range(mask + 1):
            for c in range(nch):
                v = hist[c, d]
                hist[c, d] = s
                s += v
        for c in prange(nch):
            for i in range(c * n // nch, (c + 1) * n // nch):
                d = (key[i] >> shift) & mask
                j = hist[c, d]
                hist[c, d] = j + 1
                key2[j] = key[i]
                idx2[j] = idx[i]
        key, key2 = key2, key
        idx, idx2 = idx2, idx
        shift += _SORT_BITS
    for i in prange(n):
        j = idx[i]
        ot[i] = t[j]
        ox[i] = x[j]
        oy[i] = y[j]
        op[i] = p[j]
    return ot, ox, oy, op


@njit(cache=True, parallel=True, nogil=True)
def frame_ranges(F):
    """Per-frame (min, max) of a (B, H, W) stack; NaN propagates into both."""
    B = F.shape[0]
    lo = np.empty(B)
    hi = np.empty(B)
    for b in prange(B):
        mn = math.inf
        mx = -math.inf
        bad = False
        for y in range(F.shape[1]):
            for x in range(F.shape[2]):
                v = float(F[b, y, x])
                if v != v:
                    bad = True
                if v < mn:
                    mn = v
                if v > mx:
                    mx = v
        if bad:
            mn = math.nan
            mx = math.nan
        lo[b] = mn
        hi[b] = mx
    return lo, hi


@njit(cache=True, parallel=True)
def frames_to_tiles(frames, out):
    """Tile layout of B frames: out[q * B + b] = tile q (row-major, T x T with
    T = out.shape[1]) of frame b, zero beyond the frame's edge. frames (B, H,
    W); out (n_tiles * B, T, T) of the same dtype. One pass, no padded copy,
    by rows of tiles of one frame: the frame is read along its rows (by tile,
    each of the B frames' tile rows lay on other pages: 4x slower at HD)."""
    B, H, W = frames.shape
    T = out.shape[1]
    tiles_x = (W + T - 1) // T
    tiles_y = (out.shape[0] // B) // tiles_x
    for r in prange(B * tiles_y):
        b = r // tiles_y
        ty = r - b * tiles_y
        for i in range(T):
            y = ty * T + i
            for tx in range(tiles_x):
                q = ty * tiles_x + tx
                for j in range(T):
                    x = tx * T + j
                    out[q * B + b, i, j] = frames[b, y, x] if (y < H and x < W) else 0.0
