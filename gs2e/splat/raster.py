"""Tile-based front-to-back compositing of 2D Gaussians, with hand-written backward.

Rules (3DGS, REFERENCE.md section 5):
- the image is cut in ``tile`` x ``tile`` pixel tiles; each tile holds the list
  of Gaussians whose box (3 sigma, shrunk to where alpha can reach 1/255)
  overlaps it, in increasing depth (ties by index: the sort is stable), built
  once per render;
- pixel (column j, row i) is evaluated at (j + 0.5, i + 0.5);
- a Gaussian contributes to a pixel only inside its 3-sigma ellipse
  (Mahalanobis^2 <= 9, so the result does not depend on the tile size);
- alpha = min(0.99, opacity * exp(-d^T Q d / 2)); alpha < 1/255 is skipped;
- compositing stops before the Gaussian that would bring the transmittance
  below 1e-4 (that Gaussian is not applied).

Work order (Gaussian-major, SIMD): a tile keeps the state of its pixels
(transmittance, accumulated features, where each pixel stopped) and walks its
list once, front to back (the backward: back to front). For each Gaussian and
each pixel row of the tile, the span of columns its ellipse (3 sigma, or
smaller where a low opacity keeps alpha under 1/255) can reach is solved in
closed form; the row's 8-pixel segments that the span touches are then
evaluated branch-free, 8 lanes at a time, which LLVM compiles to vector code
(AVX-512: one register per segment; AVX2: two). Every lane's state is
stored unconditionally, the values chosen by selects (:func:`_select`): no
masked stores, which only AVX-512 does at full speed. Per pixel the
operations and their order are those of a pixel-by-pixel loop, and the
exact per-pixel tests (power in [max(-4.5, log(1/255/opacity)), 0], alpha >=
1/255, pixel still open) still decide, so the spans only pre-filter and
never change a result (tested).

Per render, each Gaussian's set-up (opacity cut, footprint, row radius, 1/a)
is computed once (:func:`_prepare_gaussians`), not once per tile it reaches.

exp: vectorisable (libm's exp is a call per pixel), on [-4.5, 0] only. float64
(:func:`_exp_neg`): a table of exp(-i/64) (correctly rounded, built from
exact decimal arithmetic, so the same on every machine) times a degree-6
polynomial, within 1.4 ulp. float32 (:func:`_exp_neg_f32`): no table (a
lookup per lane is a gather, a fifth of the float32 kernel on AVX-512): 2^-i
built in the exponent bits times a degree-7 polynomial, within 1.1 ulp.

Precision: the backward and the forward it follows compute in float64 (8
lanes), products and sums rounded one by one. Renders that no backward
follows (event stage, render stage, evaluations: :func:`forward_kernel`)
composite in float32, 16 lanes, and fuse their multiply-adds
(:func:`_mul_add`: ``llvm.fma``, one rounding, the same bits on every CPU):
the same rules in the same order (tests: same bits as a float32 pixel loop
with exact fused multiply-adds; against float64 a pixel differs by rounding,
or by one Gaussian's weight where rounding moves it across a cut). Set-up,
row ranges and which segments a Gaussian reaches stay float64 in both.

Window ``smooth`` (issue 67: a render continuous in time): the same
footprint, lists and reach tests, but no jump where a Gaussian's edge
crosses a pixel and none where a pixel's compositing stops. Each Gaussian's
alpha is its exponential less the tangent line at its cut p_c (the power
where the cut window would cut it: max(-4.5, log(ALPHA_MIN / opacity))),
scaled back to its opacity at its centre:

    alpha = min(ALPHA_MAX, o phi(p) / phi(0)),  p_c <= p <= 0,
    phi(p) = exp(p) - e_c (1 + p - p_c),  e_c = exp(p_c),

zero below p_c, so alpha and its slope reach 0 together (C1), and the
opacities the cut window reaches (up to ALPHA_MAX) stay reachable (without
the scaling, alpha fell short of o by 6 % at the centre, and on a sparse
model, mouse_colmap, held-out PSNR by 1 dB). A Gaussian whose phi(0) is
under SMOOTH_PHI0_MIN (opacity under ~1.15 / 255, where phi(0) -> 0) is not
drawn: its cut window drew at most alpha 1.15 / 255, and o is constant in
time. A pixel's
weights fade out before it stops: w = alpha T r(T) with r the smoothstep
from 0 at T = T_MIN to 1 at 2 T_MIN, and the Gaussian that takes T below
T_MIN is applied (its weight already faded), so where a pixel stops no
longer changes it by a jump. What is left: the ALPHA_MAX clamp (continuous,
a kink) and, with a background other than black, bg T_final, which keeps the
product of the (1 - alpha) up to the stop (a jump of at most T_MIN |bg|).
Per Gaussian (:func:`_smooth_constants`) alpha = A exp(p) - (c0 + c1 p),
d alpha / d p = A exp(p) - c1 and d alpha / d o = u0 exp(p) - (q0 + q1 p)
(p_c and e_c depend on o where the ALPHA_MIN cut is the tighter); behind a
pixel's weights the backward sums alpha T (r + T r') f.g (the derivative of
T r(T)) where the cut window sums w f.g.

Channels: up to 4 per-Gaussian features are composited together (RGB plus
camera depth, so expected depth comes for free).

Threads: each takes a set of whole tiles chosen by their work
(:func:`tile_schedule`, longest first), not a contiguous block of them.

Determinism: each tile is handled by one thread, which writes the gradients
of its (tile, Gaussian) pairs into its own rows of a pair buffer (per pair:
lane sums in row order, then the 8 lanes in order); the buffer is then
reduced per Gaussian serially in pair order. No atomics, no fast-math, same
bits every run, whatever the thread count or vector width.
"""

from __future__ import annotations

import math
from decimal import Decimal, localcontext
from fractions import Fraction

import numba
import numpy as np
from llvmlite import ir as llvm_ir
from numba import njit, prange
from numba.extending import intrinsic, overload

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1.0e-4
POWER_MIN = -4.5  # 3 sigma: -0.5 * 3^2
WINDOWS = ("cut", "smooth")  # the rasteriser's window (module docstring)
SMOOTH_PHI0_MIN = 0.01  # smooth window: Gaussians with a smaller phi(0) are not drawn
MAX_CHANNELS = 4
LANES = 8  # pixels per segment: one AVX-512 register of float64


def _exp_table() -> np.ndarray:
    """exp(-i/64), i = 0..291, correctly rounded to float64 (from 40-digit
    decimals, so the same on every machine)."""
    with localcontext() as ctx:
        ctx.prec = 40
        return np.array([float((-Decimal(i) / 64).exp()) for i in range(292)])


EXP_TAB = _exp_table()


@njit(inline="always", fastmath=False)
def _exp_neg(x):
    """float64 exp for x in [-4.5 - 1e-5, 0] (the compositing range; others:
    do not call): exp(-i/64) from :data:`EXP_TAB` times exp(r), |r| <= 1/128,
    by its Taylor polynomial to degree 6 (Horner); within 1.4 ulp of exp on
    [-4.5, 0] (tests). The float64 kernels (training's forward and backward)
    use it."""
    i = np.int32(x * -64.0 + 0.5)
    r = x + float(i) * 0.015625  # exact: i / 64 and x share their last bits
    t = 1.0 + r * (0.5 + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0)))))
    e = EXP_TAB[i]
    return e + e * (r * t)


def _round_f32(exact: Fraction) -> np.float32:
    """The float32 nearest to a rational (ties to even), for the Python
    reference of :func:`_mul_add`."""
    f = np.float32(float(exact))
    cands = (np.nextafter(f, np.float32(-np.inf)), f, np.nextafter(f, np.float32(np.inf)))
    return min(cands, key=lambda v: (abs(Fraction(float(v)) - exact),
                                     int(np.array(v).view(np.int32)) & 1))


def _mul_add(a, b, c):
    """a * b + c. All float32: fused, one rounding of the exact value
    (``llvm.fma``, correctly rounded on every CPU: a single instruction where
    the CPU has FMA, a library call otherwise, the same bits either way).
    Otherwise a product then a sum, two roundings, as written: the float64
    kernels keep the plain arithmetic that the backward recomputes. This
    Python body is the reference (exact rationals); compiled code uses the
    overload below."""
    if all(isinstance(v, np.float32) for v in (a, b, c)):
        return _round_f32(Fraction(float(a)) * Fraction(float(b)) + Fraction(float(c)))
    return a * b + c


@intrinsic
def _fma_f32(typingctx, a, b, c):
    sig = numba.types.float32(numba.types.float32, numba.types.float32, numba.types.float32)

    def codegen(context, builder, signature, args):
        f = llvm_ir.FloatType()
        fn = builder.module.declare_intrinsic("llvm.fma", [f], llvm_ir.FunctionType(f, [f, f, f]))
        return builder.call(fn, args)

    return sig, codegen


@overload(_mul_add, inline="always")
def _mul_add_impl(a, b, c):
    f32 = numba.types.float32
    if a == f32 and b == f32 and c == f32:
        return lambda a, b, c: _fma_f32(a, b, c)
    return lambda a, b, c: a * b + c


def _select(c, a, b):
    """``a if c else b`` with both evaluated: an LLVM ``select`` (compiled
    code, the overload below), so that a lane's conditional update is a
    blend and an unconditional store. Written as a Python conditional, the
    update compiled to masked loads and stores (``vmaskmovps``), which
    AVX-512 does at full speed and AVX2 machines slowly (microcoded on AMD
    Zen: the float32 forward ran 1.5x slower for it). a and b share a type."""
    return a if c else b


@intrinsic
def _select_intr(typingctx, c, a, b):
    if a != b:
        return None
    sig = a(numba.types.boolean, a, b)

    def codegen(context, builder, signature, args):
        return builder.select(args[0], args[1], args[2])

    return sig, codegen


@overload(_select, inline="always")
def _select_impl(c, a, b):
    if a == b:
        return lambda c, a, b: _select_intr(c, a, b)


def _pow2_neg_f32(i):
    """2**-i as a float32, for an integer i in [0, 126] (exact)."""
    return np.float32(2.0 ** -int(i))


@overload(_pow2_neg_f32, inline="always")
def _pow2_neg_f32_impl(i):
    return lambda i: np.int32((np.int32(127) - i) << np.int32(23)).view(np.float32)


_F32 = np.float32
_LOG2E_F32 = _F32(1.4426950408889634)
_LN2_HI_F32 = _F32(0.693359375)  # 9 significant bits: i * _LN2_HI_F32 is exact for i < 2^15
_LN2_LO_F32 = _F32(math.log(2.0) - 0.693359375)
_EXP_C_F32 = tuple(_F32(1.0 / math.factorial(k)) for k in range(1, 8))  # 1/1! .. 1/7!


@njit(inline="always", fastmath=False)
def _exp_neg_f32(x):
    """float32 exp for x in [-4.5 - 1e-5, 0] (the compositing range; others:
    do not call): 2^-i, i = round(-x / ln 2), built in the exponent bits,
    times exp(r), r = x + i ln 2 (Cody-Waite, |r| <= 0.35), by its Taylor
    polynomial to degree 7 in fused multiply-adds; within 1.1 float32 ulp of
    exp on [-4.5, 0] (tests). No table: a table lookup per lane is a gather,
    a fifth of the float32 kernel's time on AVX-512."""
    i = np.int32(_mul_add(x, -_LOG2E_F32, _F32(0.5)))
    fi = np.float32(i)
    r = _mul_add(fi, _LN2_LO_F32, _mul_add(fi, _LN2_HI_F32, x))
    c1, c2, c3, c4, c5, c6, c7 = _EXP_C_F32
    t = _mul_add(r, _mul_add(r, _mul_add(r, _mul_add(r, _mul_add(r, _mul_add(r, c7, c6), c5),
                                                      c4), c3), c2), c1)
    e = _pow2_neg_f32(i)
    return _mul_add(e * r, t, e)


def _exp_neg_any(x):
    """:func:`_exp_neg_f32` for a float32, :func:`_exp_neg` otherwise."""
    return _exp_neg_f32(x) if isinstance(x, np.float32) else _exp_neg(x)


@overload(_exp_neg_any, inline="always")
def _exp_neg_any_impl(x):
    if x == numba.types.float32:
        return lambda x: _exp_neg_f32(x)
    return lambda x: _exp_neg(x)


@njit(cache=True, fastmath=False)
def _tile_rect(u, v, r, width, height, tile, tiles_x, tiles_y):
    """Inclusive tile range [x0, x1] x [y0, y1] whose pixel centres the box reaches."""
    j0 = max(0, int(math.ceil(u - r - 0.5)))
    j1 = min(width - 1, int(math.floor(u + r - 0.5)))
    i0 = max(0, int(math.ceil(v - r - 0.5)))
    i1 = min(height - 1, int(math.floor(v + r - 0.5)))
    if j0 > j1 or i0 > i1:
        return 0, -1, 0, -1
    return j0 // tile, j1 // tile, i0 // tile, i1 // tile


@njit(cache=True, parallel=True, fastmath=False)
def bin_kernel(order, means2d, radii, width, height, tile, n_workers=1):
    """Per-tile Gaussian lists in the given (depth) order, built by
    ``n_workers`` threads.

    Returns tile_offsets (n_tiles+1,) int64 and tile_gids (n_pairs,) int32:
    :func:`bin_rects_kernel` on each Gaussian's tile range (:func:`_tile_rect`
    of its box, radius ``radii``).
    """
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    n = order.shape[0]
    rect = np.empty((n, 4), dtype=np.int32)  # per position of order, empty if y0 > y1
    for gi in prange(n):
        g = order[gi]
        r = float(radii[g])
        x0, x1, y0, y1 = 0, -1, 0, -1
        if r > 0:
            x0, x1, y0, y1 = _tile_rect(float(means2d[g, 0]), float(means2d[g, 1]), r,
                                        width, height, tile, tiles_x, tiles_y)
        rect[gi, 0], rect[gi, 1], rect[gi, 2], rect[gi, 3] = x0, x1, y0, y1
    return bin_rects_kernel(order, rect, width, height, tile, n_workers)


@njit(cache=True, parallel=True, fastmath=False)
def bin_rects_kernel(order, rect, width, height, tile, n_workers=1):
    """Per-tile lists of the Gaussians ``order`` (n,) (in that order) from
    their tile ranges rect (n, 4) int32, row k that of order[k] (read row
    after row): x0, x1, y0, y1 inclusive, empty if y0 > y1. Returns
    tile_offsets (n_tiles+1,) int64 and tile_gids (n_pairs,) int32.

    Parallel over bands of tile rows, each walking every Gaussian in order and
    writing only its own tiles (so the lists are the same whatever the thread
    count); bands go to threads in turn, as the busy rows of a view are often
    next to each other.
    """
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    n_tiles = tiles_x * tiles_y
    n = order.shape[0]
    n_workers = max(1, min(n_workers, tiles_y))
    band = max(1, tiles_y // (4 * n_workers))  # tile rows per band
    n_bands = (tiles_y + band - 1) // band
    counts = np.zeros(n_tiles + 1, dtype=np.int64)
    for w in prange(n_workers):
        for k in range(w, n_bands, n_workers):
            ya, yb = k * band, min(tiles_y, (k + 1) * band) - 1
            for gi in range(n):
                y0, y1 = max(rect[gi, 2], ya), min(rect[gi, 3], yb)
                for ty in range(y0, y1 + 1):
                    for tx in range(rect[gi, 0], rect[gi, 1] + 1):
                        counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    fill = counts[:-1].copy()
    gids = np.empty(counts[n_tiles], dtype=np.int32)
    for w in prange(n_workers):
        for k in range(w, n_bands, n_workers):
            ya, yb = k * band, min(tiles_y, (k + 1) * band) - 1
            for gi in range(n):
                y0, y1 = max(rect[gi, 2], ya), min(rect[gi, 3], yb)
                for ty in range(y0, y1 + 1):
                    for tx in range(rect[gi, 0], rect[gi, 1] + 1):
                        t = ty * tiles_x + tx
                        gids[fill[t]] = order[gi]
                        fill[t] += 1
    return counts, gids


@njit(cache=True, fastmath=False)
def resort_by_depth(prev, visible, depths, max_moves):
    """The Gaussians with ``visible`` (N,) bool in increasing depth, ties by
    index (what a stable argsort of the visible indices by depth gives),
    starting from ``prev``, the order of a nearby pose: its members still
    visible keep their order, the newly visible follow by index, and an
    insertion sort by (depth, index) finishes. Between an event stage's
    samples the camera barely moves and few moves are needed. Returns
    (order, True), or (anything, False) once more than ``max_moves`` moves
    were needed (the caller sorts from scratch)."""
    n = visible.shape[0]
    inprev = np.zeros(n, dtype=np.bool_)
    m = 0
    for k in range(prev.shape[0]):
        inprev[prev[k]] = True
        m += visible[prev[k]]
    for g in range(n):
        m += visible[g] and not inprev[g]
    out = np.empty(m, dtype=np.int64)
    c = 0
    for k in range(prev.shape[0]):
        if visible[prev[k]]:
            out[c] = prev[k]
            c += 1
    for g in range(n):
        if visible[g] and not inprev[g]:
            out[c] = g
            c += 1
    moves = 0
    for i in range(1, m):
        g = out[i]
        d = depths[g]
        j = i
        while j > 0:
            h = out[j - 1]
            if depths[h] < d or (depths[h] == d and h < g):
                break
            out[j] = h
            j -= 1
        moves += i - j
        if moves > max_moves:
            return out, False
        out[j] = g
    return out, True


@njit(cache=True, fastmath=False)
def _schedule_kernel(cost, rank, order, bounds):
    """Longest-first greedy split of positions 0..n-1 over len(bounds) - 1
    workers: in the order ``rank`` (by decreasing cost, ties: lower position
    first), each position goes to the worker with the least cost so far (ties:
    lower worker). order gets each worker's positions ascending, worker after
    worker."""
    n = cost.shape[0]
    n_workers = bounds.shape[0] - 1
    load = np.zeros(n_workers)
    owner = np.empty(n, dtype=np.int64)
    counts = np.zeros(n_workers, dtype=np.int64)
    for r in range(n):
        w = 0
        for k in range(1, n_workers):
            if load[k] < load[w]:
                w = k
        owner[rank[r]] = w
        load[w] += cost[rank[r]]
        counts[w] += 1
    bounds[0] = 0
    for w in range(n_workers):
        bounds[w + 1] = bounds[w] + counts[w]
    fill = bounds[:-1].copy()
    for i in range(n):
        order[fill[owner[i]]] = i
        fill[owner[i]] += 1


def tile_schedule(offsets: np.ndarray, n_workers: int | None = None):
    """Split the tiles of a tile list over threads by their work.

    ``prange`` gives each thread one contiguous block of iterations, so on a
    real scene one thread got the busy tiles while the other waited (temple_ring
    at 328x242: the top half of the tiles holds 62 % of the pairs, and two
    threads rendered 1.59x faster than one, not 2x). The compositing kernels
    loop over workers instead, each walking the tiles given here.

    Parameters
    ----------
    offsets : (n_tiles+1,) int64 tile list bounds; a tile's cost is taken as
        its number of pairs plus 16 for its pixels.
    n_workers : default :func:`numba.get_num_threads`.

    Returns
    -------
    order (n_tiles,) int64 positions in the tile list, worker after worker,
    and bounds (n_workers+1,) int64. Which thread renders a tile never changes
    a result: a tile writes only its own pixels and pair rows.
    """
    if n_workers is None:
        n_workers = numba.get_num_threads()
    cost = np.diff(offsets).astype(np.float64) + 16.0
    order = np.empty(cost.shape[0], dtype=np.int64)
    bounds = np.zeros(max(1, int(n_workers)) + 1, dtype=np.int64)
    # numpy's stable sort, not numba's: the same order, and numba's mergesort
    # cost ~2.7 CPU-s of every cold compile
    _schedule_kernel(cost, np.argsort(-cost, kind="stable"), order, bounds)
    return order, bounds


@njit(fastmath=False)
def _tile_origin(t, tiles_x, tile, width, height):
    """Top-left pixel (x0, y0) and size (tw, th) of tile t (row-major)."""
    ty = t // tiles_x
    tx = t - ty * tiles_x
    x0 = tx * tile
    y0 = ty * tile
    return x0, y0, min(width, x0 + tile) - x0, min(height, y0 + tile) - y0


@njit(fastmath=False)
def _footprint(o, a, b, c):
    """lpm, the power below which a Gaussian of opacity ``o`` and conic
    (a, b, c) cannot pass (the 3-sigma cut or alpha < 1/255, whichever is
    tighter, minus a margin), and m2 = -2 lpm, the squared Mahalanobis radius
    of that ellipse; lpm = 1 (never passes) for alpha < 1/255 everywhere or a
    degenerate conic."""
    det = a * c - b * b
    if o < ALPHA_MIN or not det > 0.0:
        return 1.0, 0.0, det
    lpm = max(POWER_MIN, math.log(ALPHA_MIN / o)) - 1e-6
    return lpm, -2.0 * lpm, det


@njit(fastmath=False)
def _gaussian(g, means2d, conics, opac, feats):
    """Gaussian g as float64 scalars: opacity, conic (a, b, c), its footprint
    (lpm, m2, det: :func:`_footprint`), centre (u, v) and features padded to
    4 with zeros."""
    # np.float64, not float(): numba's float() keeps a float32 a float32, and
    # det = a c - b^2 in float32 cancels for needles, so that the reach tests
    # missed pixels at their tips that the per-pixel test keeps
    C = feats.shape[1]
    o = np.float64(opac[g])
    a = np.float64(conics[g, 0])
    b = np.float64(conics[g, 1])
    c = np.float64(conics[g, 2])
    lpm, m2, det = _footprint(o, a, b, c)
    f1 = np.float64(feats[g, 1]) if C > 1 else 0.0
    f2 = np.float64(feats[g, 2]) if C > 2 else 0.0
    f3 = np.float64(feats[g, 3]) if C > 3 else 0.0
    return (o, a, b, c, lpm, m2, det, np.float64(means2d[g, 0]), np.float64(means2d[g, 1]),
            np.float64(feats[g, 0]), f1, f2, f3)


_NGEO_CUT = 15  # per-Gaussian set-up: _gaussian's 13, row radius, 1 / a
_NGEO = 22  # and the smooth window's 7 (_smooth_constants)


# Per render, per tile and per Gaussian helpers are compiled functions of their
# own, not inlined into the compositing kernels (the per-pair, per-row and
# per-segment ones are): inlined, their IR and this loop's parfor went into
# each of the four kernels' cold compile (float32 forward 10.0 -> 7.6 CPU-s, plus
# 1.4 once for this kernel), for no measurable speed (interleaved renders, same bits).
@njit(parallel=True, cache=True, fastmath=False)
def _prepare_gaussians(means2d, conics, opac, feats, smooth):
    """(N, _NGEO_CUT) float64, or with ``smooth`` (N, _NGEO) holding the
    smooth window's constants too: per Gaussian, :func:`_gaussian`'s values, the row
    radius of the rows it reaches (:func:`_rows_of`; power >= lpm, slightly
    enlarged) and 1 / a, computed once per render instead of once per (tile,
    Gaussian) pair (a Gaussian reaches ~30 tiles at HD)."""
    n = means2d.shape[0]
    geo = np.zeros((n, _NGEO if smooth else _NGEO_CUT))
    for g in prange(n):
        o, a, b, c, lpm, m2, det, u, v, f0, f1, f2, f3 = _gaussian(g, means2d, conics, opac, feats)
        geo[g, 0], geo[g, 1], geo[g, 2], geo[g, 3], geo[g, 4] = o, a, b, c, lpm
        geo[g, 5], geo[g, 6], geo[g, 7], geo[g, 8] = m2, det, u, v
        geo[g, 9], geo[g, 10], geo[g, 11], geo[g, 12] = f0, f1, f2, f3
        if lpm <= 0.0:
            geo[g, 13] = math.sqrt(m2 * a / det) * (1.0 + 1e-6) + 1e-3  # var_y = a / det
            geo[g, 14] = 1.0 / a
            if smooth:
                k = _smooth_constants(o)
                for i in range(_NGEO - _NGEO_CUT):
                    geo[g, _NGEO_CUT + i] = k[i]
    return geo


@njit(fastmath=False)
def _smooth_constants(o):
    """The smooth window's constants of a Gaussian of opacity ``o`` >=
    ALPHA_MIN (module docstring): (p_c, A, c0, c1, u0, q0, q1) with alpha =
    A exp(p) - (c0 + c1 p) and d alpha / d o = u0 exp(p) - (q0 + q1 p) on
    [p_c, 0]; all 0 (not drawn) where phi(0) < SMOOTH_PHI0_MIN."""
    e0 = math.exp(POWER_MIN)
    big = o * e0 >= ALPHA_MIN
    pc = POWER_MIN if big else math.log(ALPHA_MIN / o)
    ec = e0 if big else ALPHA_MIN / o
    phi0 = 1.0 - ec * (1.0 - pc)
    if not phi0 >= SMOOTH_PHI0_MIN:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    A = o / phi0
    c1 = A * ec
    c0 = c1 * (1.0 - pc)
    if big:  # p_c, e_c fixed: d alpha / d o = phi(p) / phi(0)
        u0, q1 = 1.0 / phi0, ec / phi0
        q0 = q1 * (1.0 - pc)
    else:  # e_c = ALPHA_MIN / o, p_c = log(e_c): their derivatives in o too
        r = ec / phi0
        u0 = (1.0 + r * pc) / phi0
        q1 = (1.0 + r * pc) * ec / phi0 - r
        q0 = (1.0 + r * pc) * ec * (1.0 - pc) / phi0 + r * pc
    return pc, A, c0, c1, u0, q0, q1


@njit(inline="always", fastmath=False)
def _segment_values(geo, g, ftype):
    """Gaussian g's values as the segments take them, in ``ftype``: opacity,
    conic (a, b, c), lpm, centre (u, v), features 0..3 (one place for the
    forward and the backward kernels, which must see the same values)."""
    return (ftype(geo[g, 0]), ftype(geo[g, 1]), ftype(geo[g, 2]), ftype(geo[g, 3]),
            ftype(geo[g, 4]), ftype(geo[g, 7]), ftype(geo[g, 8]), ftype(geo[g, 9]),
            ftype(geo[g, 10]), ftype(geo[g, 11]), ftype(geo[g, 12]))


@njit(inline="always", fastmath=False)
def _smooth_values(geo, g, ftype):
    """Gaussian g's smooth-window constants (p_c, A, c0, c1, u0, q0, q1:
    :func:`_smooth_constants`) in ``ftype``."""
    k = _NGEO_CUT
    return (ftype(geo[g, k]), ftype(geo[g, k + 1]), ftype(geo[g, k + 2]), ftype(geo[g, k + 3]),
            ftype(geo[g, k + 4]), ftype(geo[g, k + 5]), ftype(geo[g, k + 6]))


@njit(inline="always", fastmath=False)
def _rows_of(v, ry, y0, th):
    """Rows (tile-local, inclusive) whose centre lies within ``ry`` of the
    centre row v."""
    return (max(0, int(math.ceil(v - ry - 0.5)) - y0),
            min(th - 1, int(math.floor(v + ry - 0.5)) - y0))


@njit(inline="always", fastmath=False)
def _row_reached(u, dy, a, b, det, m2, inv_a, x0, tw):
    """Whether the ellipse a dx^2 + 2 b dx dy + c dy^2 <= m2 may reach one of
    the pixel centres x0 + 0.5 .. x0 + tw - 0.5 of the row at offset dy = v - py
    from its centre row (a tile row, or one segment of it; inv_a = 1 / a).

    Decided by squared distances, without a square root or a rounding to
    columns: the distance from the chord's centre cx to that span, less
    2e-3 px, is compared with the half-chord sqrt(D) / a widened by a
    relative 1e-5. So every span holding a column that the column rule keeps
    (the chord solved for dx, widened by 1e-6 relative and 1e-3 px:
    ``tests/test_splat_raster_exact.py``) is kept; the margins cover the
    rounding of either side. A span kept with no pixel in reach composites
    nothing: every pixel is tested exactly in the segment. Branch-free (the
    kernels evaluate it for all of a Gaussian's rows at once, as vector
    code)."""
    D = a * m2 - det * dy * dy + 1e-6 * a * m2
    cx = u + b * dy * inv_a
    d = max(0.0, max(x0 + 0.5 - cx, cx - (x0 + tw - 0.5))) - 2e-3  # less a margin
    return (not D < 0.0) & (not ((d > 0.0) & (d * d > D * inv_a * inv_a * (1.0 + 1e-5))))


@njit(inline="always", fastmath=False)
def _rows_reached(reached, i_lo, i_hi, u, v, a, b, det, m2, inv_a, x0, y0, tw, lanes, nseg,
                  per_segment):
    """Which segments of tile rows i_lo..i_hi (tile origin x0, y0) the
    ellipse may reach (:func:`_row_reached`), for all rows at once in loops
    without branches, which LLVM vectorises: with ``per_segment`` (the
    8-lane kernels, a constant of the kernel) reached[ii * nseg + h] for
    every segment h; else, with one segment per row, reached[ii] (with
    several, :func:`_row_segments` tests one row at a time). Solving each
    row's chord for its columns instead (a square root and two roundings per
    row) took a quarter of the float32 forward's time at HD, and made the
    float64 training passes 1.18-1.21x slower at DAVIS346; a test and branch
    per row cost ~7 % more."""
    if per_segment:
        for h in range(nseg):
            ws = min(lanes, tw - h * lanes)
            for ii in range(i_lo, i_hi + 1):
                reached[ii * nseg + h] = (ws > 0) & _row_reached(u, v - (y0 + ii + 0.5), a, b, det,
                                                                 m2, inv_a, x0 + h * lanes, ws)
    elif nseg == 1:
        for ii in range(i_lo, i_hi + 1):
            reached[ii] = _row_reached(u, v - (y0 + ii + 0.5), a, b, det, m2, inv_a, x0, tw)


@njit(inline="always", fastmath=False)
def _segments_of(u, dy, a, b, det, m2, inv_a, x0, tw, lanes, nseg):
    """Segments of ``lanes`` columns (inclusive; empty if lo > hi) of the tile
    row (origin x0, width tw) at offset dy from the centre row that the
    ellipse may reach: :func:`_row_reached` on each segment's pixel centres,
    for one row."""
    lo, hi = nseg, -1
    for h in range(nseg):
        ws = min(lanes, tw - h * lanes)
        if ws > 0 and _row_reached(u, dy, a, b, det, m2, inv_a, x0 + h * lanes, ws):
            lo = min(lo, h)
            hi = h
    return (lo, hi) if hi >= 0 else (0, -1)


@njit(inline="always", fastmath=False)
def _row_segments(reached, ii, u, v, a, b, det, m2, inv_a, x0, y0, tw, lanes, nseg, per_segment):
    """Segments (inclusive; empty if lo > hi) of tile row ii that the kernels
    composite for a Gaussian: what :func:`_rows_reached` found (the reached
    segments of a row are contiguous: the chord is an interval), or, for
    the 16-lane kernels on tiles wider than 16, :func:`_segments_of`. The
    16-lane kernels carry no per-segment code in their hot loop: inlined,
    it slowed them by ~5 % at HD."""
    if per_segment:
        if nseg == 2:  # the 8-lane kernels on 16-pixel tiles: no loop (2-5 % of their forward)
            r0 = reached[2 * ii]
            r1 = reached[2 * ii + 1]
            return (0 if r0 else 1), (1 if r1 else (0 if r0 else -1))
        lo, hi = nseg, -1
        for h in range(nseg):
            if reached[ii * nseg + h]:
                lo = min(lo, h)
                hi = h
        return (lo, hi) if hi >= 0 else (0, -1)
    if nseg == 1:
        return (0, 0) if reached[ii] else (0, -1)
    return _segments_of(u, v - (y0 + ii + 0.5), a, b, det, m2, inv_a, x0, tw, lanes, nseg)


@njit(inline="always", fastmath=False)
def _lane_alpha(jx, lf, u, a, b, c, dy, lpm, o, kc):
    """One lane's alpha with the cut window (column jx + lf at offset dy from
    the centre row) and whether the Gaussian reaches that pixel (the cut:
    3 sigma and alpha >= ALPHA_MIN), before the pixel's own state."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    dx = u - ((jx + lf) + half)
    # -1/2 (a dx^2 + c dy^2) - b dx dy
    power = _mul_add(-(b * dx), dy, -half * _mul_add(a * dx, dx, c * dy * dy))
    # exp's argument is clamped to its domain, not masked by the pixel
    # state: the exp then does not wait for the previous Gaussian's
    # result on these pixels (a loop-carried chain; 1.1-1.2x faster)
    alpha = min(a_max, o * _exp_neg_any(min(max(power, p_min), zero)))
    return alpha, (power <= zero) & (power >= lpm) & (power >= p_min) & (alpha >= a_min)


@njit(inline="always", fastmath=False)
def _lane_apply(s, at, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc):
    """Composite one lane's alpha (:func:`_lane_alpha`) into the pixel state
    at s[at:] of a segment block with the cut window."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    FT, F0, F1, F2, F3, FL = at, at + lanes, at + 2 * lanes, at + 3 * lanes, at + 4 * lanes, at + 5 * lanes
    ok = reach & (s[FL + lane] == mf)
    T = s[FT + lane]
    t_next = T * (one - alpha)
    upd = ok & (t_next >= t_min)
    w = alpha * T
    # Every store unconditional and no select between a stored value and
    # the value loaded from the same place: LLVM turns that into a masked
    # store (see _select). The same bits: a lane not updated adds f * 0 to
    # a sum that is never -0 (it starts at +0; features are finite),
    # multiplies T by 1 and adds 0 to its stop index (exact integers).
    wu = _select(upd, w, zero)
    s[F0 + lane] = _mul_add(f0, wu, s[F0 + lane])
    s[F1 + lane] = _mul_add(f1, wu, s[F1 + lane])
    s[F2 + lane] = _mul_add(f2, wu, s[F2 + lane])
    s[F3 + lane] = _mul_add(f3, wu, s[F3 + lane])
    s[FT + lane] = T * _select(upd, one - alpha, one)  # t_next where updated
    s[FL + lane] = s[FL + lane] + _select(ok & (t_next < t_min), kf - mf, zero)  # open = mf


@njit(inline="always", fastmath=False)
def _segment_forward(s, at, pair, jx, u, a, b, c, dy, lpm, o, f0, f1, f2, f3, kf, mf, lanes,
                     lane_f, kc):
    """Composite Gaussian k (kf = k) over the ``lanes`` pixels of one segment
    block (columns jx .. jx + lanes - 1 at offset dy from the centre row; jx
    given in the float type), in the float type of the block and values: into
    the pixel state at s[at:], or with ``pair`` into both states s[0:] and
    s[6 lanes:] (the same pixels composited in two depth orders,
    :func:`_make_forward`), each alpha computed once.
    Branch-free: every lane computes and stores, selects decide what. A
    pixel is open while its stop index equals mf (list length). lane_f = 0 ..
    lanes - 1; kc = (0, 1, 0.5, ALPHA_MAX, ALPHA_MIN, T_MIN, POWER_MIN); all
    in that type. Multiply-adds go through :func:`_mul_add` (fused in float32)
    and exp through :func:`_exp_neg_any`."""
    if pair:
        for lane in range(lanes):
            alpha, reach = _lane_alpha(jx, lane_f[lane], u, a, b, c, dy, lpm, o, kc)
            _lane_apply(s, 0, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc)
            _lane_apply(s, 6 * lanes, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc)
    else:
        for lane in range(lanes):
            alpha, reach = _lane_alpha(jx, lane_f[lane], u, a, b, c, dy, lpm, o, kc)
            _lane_apply(s, at, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc)


@njit(inline="always", fastmath=False)
def _ramp(T, t_min, inv_t_min, zero, one, two, three):
    """r(T), the smooth window's fade of a pixel's weights before it stops
    (smoothstep from 0 at T = t_min to 1 at 2 t_min), and r'(T)."""
    x = min(one, max(zero, (T - t_min) * inv_t_min))
    return x * x * (three - two * x), (two * three) * x * (one - x) * inv_t_min


@njit(inline="always", fastmath=False)
def _lane_alpha_smooth(jx, lf, u, a, b, c, dy, pc, c0, c1, o, kc):
    """:func:`_lane_alpha` with the smooth window: alpha = min(ALPHA_MAX,
    o exp(p) - (c0 + c1 p)) on [p_c, 0] (``o``: the Gaussian's A of
    :func:`_smooth_constants`)."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    dx = u - ((jx + lf) + half)
    power = _mul_add(-(b * dx), dy, -half * _mul_add(a * dx, dx, c * dy * dy))
    G = _exp_neg_any(min(max(power, p_min), zero))
    alpha = min(a_max, max(zero, _mul_add(o, G, -_mul_add(c1, power, c0))))
    return alpha, (power <= zero) & (power >= pc)


@njit(inline="always", fastmath=False)
def _lane_apply_smooth(s, at, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc, ks):
    """:func:`_lane_apply` with the smooth window: weights faded by r(T), the
    stopping Gaussian applied and counted (stop index k + 1)."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    two, three, inv_t_min = ks
    FT, F0, F1, F2, F3, FL = at, at + lanes, at + 2 * lanes, at + 3 * lanes, at + 4 * lanes, at + 5 * lanes
    ok = reach & (s[FL + lane] == mf)
    T = s[FT + lane]
    r = _ramp(T, t_min, inv_t_min, zero, one, two, three)[0]
    t_next = T * (one - alpha)
    wu = _select(ok, alpha * T * r, zero)
    s[F0 + lane] = _mul_add(f0, wu, s[F0 + lane])
    s[F1 + lane] = _mul_add(f1, wu, s[F1 + lane])
    s[F2 + lane] = _mul_add(f2, wu, s[F2 + lane])
    s[F3 + lane] = _mul_add(f3, wu, s[F3 + lane])
    s[FT + lane] = T * _select(ok, one - alpha, one)
    s[FL + lane] = s[FL + lane] + _select(ok & (t_next < t_min), (kf + one) - mf, zero)


@njit(inline="always", fastmath=False)
def _segment_forward_smooth(s, at, pair, jx, u, a, b, c, dy, pc, c0, c1, o, f0, f1, f2, f3, kf,
                            mf, lanes, lane_f, kc, ks):
    """:func:`_segment_forward` with the smooth window (module docstring).
    ks = (2, 3, 1 / T_MIN) in the block's type. (Leaving the fade out of
    blocks where it is 1, as the backward does, did not pay here: the fade
    is a few of the forward's operations per pixel.)"""
    if pair:
        for lane in range(lanes):
            alpha, reach = _lane_alpha_smooth(jx, lane_f[lane], u, a, b, c, dy, pc, c0, c1, o, kc)
            _lane_apply_smooth(s, 0, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc, ks)
            _lane_apply_smooth(s, 6 * lanes, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc,
                               ks)
    else:
        for lane in range(lanes):
            alpha, reach = _lane_alpha_smooth(jx, lane_f[lane], u, a, b, c, dy, pc, c0, c1, o, kc)
            _lane_apply_smooth(s, at, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc, ks)


@njit(inline="always", fastmath=False)
def _lane_tangent(s, lane, lanes, jx, lf, u, a, b, c, dy, pc, c0, c1, A, f0, f1, f2, f3, d, kf, mf,
                  kc, ks):
    """:func:`_lane_apply_smooth` of :func:`_lane_alpha_smooth`'s alpha (the
    same operations: the same bits) and, ahead of it, the time derivative of
    the pixel's state (the tangent pass, :mod:`gs2e.splat.tangent`): d =
    (du, dv, d conic a, b, c, d features 0..3) of the Gaussian; block fields
    6 (dT) and 7..10 (d features) after the value's 6. d alpha = (A e^p - c1)
    dp where alpha is not clamped, d w = d alpha T r + alpha dT (r + T r'),
    dT' = dT (1 - alpha) - T d alpha."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    two, three, inv_t_min = ks
    du, dv, dca, dcb, dcc, e0, e1, e2, e3 = d
    dx = u - ((jx + lf) + half)
    power = _mul_add(-(b * dx), dy, -half * _mul_add(a * dx, dx, c * dy * dy))
    G = _exp_neg_any(min(max(power, p_min), zero))
    a_raw = _mul_add(A, G, -_mul_add(c1, power, c0))
    alpha = min(a_max, max(zero, a_raw))
    reach = (power <= zero) & (power >= pc)
    ok = reach & (s[5 * lanes + lane] == mf)
    dp = (-(a * dx + b * dy) * du - (b * dx + c * dy) * dv - half * (dca * dx * dx + dcc * dy * dy)
          - dcb * dx * dy)
    dal = _select(ok & (a_raw >= zero) & (a_raw <= a_max), (A * G - c1) * dp, zero)
    T = s[lane]
    dT = s[6 * lanes + lane]
    r, dr = _ramp(T, t_min, inv_t_min, zero, one, two, three)
    wu = _select(ok, alpha * T * r, zero)
    dwu = _select(ok, dal * T * r + alpha * dT * (r + T * dr), zero)
    s[7 * lanes + lane] = s[7 * lanes + lane] + (dwu * f0 + wu * e0)
    s[8 * lanes + lane] = s[8 * lanes + lane] + (dwu * f1 + wu * e1)
    s[9 * lanes + lane] = s[9 * lanes + lane] + (dwu * f2 + wu * e2)
    s[10 * lanes + lane] = s[10 * lanes + lane] + (dwu * f3 + wu * e3)
    s[6 * lanes + lane] = dT * (one - _select(ok, alpha, zero)) - T * dal
    _lane_apply_smooth(s, 0, lane, lanes, alpha, reach, f0, f1, f2, f3, kf, mf, kc, ks)


@njit(inline="always", fastmath=False)
def _block_open(st, at, mf, lanes):
    """Whether any of the stop indices st[at:at + lanes] is still open
    (== mf): a block whose pixels have all stopped is left alone, as the
    branch-free segment would leave it (about a fifth of the blocks a
    trained model's Gaussians reach, behind opaque surfaces)."""
    for lane in range(lanes):
        if st[at + lane] == mf:
            return True
    return False


@njit(inline="always", fastmath=False)
def _composite_gaussian(geo, g, kf, st, at, pair, nstates, reached, x0, y0, tw, th, mf, smooth,
                        ftype, lanes, nseg, per_segment, FBLK, FL, lane_f, kc, ks, tangent, dgeo):
    """Composite Gaussian g, list position kf, into a tile's segment blocks,
    each holding ``nstates`` pixel states of FBLK values one after the other:
    into the state at offset ``at``, or with ``pair`` into the first two
    with the same alphas. A block whose pixels have stopped in every state
    it composites into is left alone. With ``tangent`` (the smooth window,
    one state): the pixels' time derivatives too, from the Gaussian's rates
    dgeo[g] (:func:`_lane_tangent`)."""
    lpm = geo[g, 4]
    if lpm > 0.0:
        return
    half = ftype(0.5)
    a, b, m2, det, u, v = geo[g, 1], geo[g, 2], geo[g, 5], geo[g, 6], geo[g, 7], geo[g, 8]
    inv_a = geo[g, 14]
    o_f, a_f, b_f, c_f, lpm_f, u_f, v_f, f0, f1, f2, f3 = _segment_values(geo, g, ftype)
    i_lo, i_hi = _rows_of(v, geo[g, 13], y0, th)
    _rows_reached(reached, i_lo, i_hi, u, v, a, b, det, m2, inv_a, x0, y0, tw, lanes, nseg,
                  per_segment)
    stride = nstates * FBLK
    for ii in range(i_lo, i_hi + 1):
        h_lo, h_hi = _row_segments(reached, ii, u, v, a, b, det, m2, inv_a, x0, y0, tw, lanes,
                                   nseg, per_segment)
        if h_lo > h_hi:
            continue
        dy_f = v_f - (ftype(y0 + ii) + half)
        for h in range(h_lo, h_hi + 1):
            blk = (ii * nseg + h) * stride
            if not (_block_open(st, blk + at + FL, mf, lanes)
                    or (pair and _block_open(st, blk + FBLK + FL, mf, lanes))):
                continue
            if smooth and tangent:
                pc_f, A_f, c0_f, c1_f, _u0, _q0, _q1 = _smooth_values(geo, g, ftype)
                d = (ftype(dgeo[g, 0]), ftype(dgeo[g, 1]), ftype(dgeo[g, 2]), ftype(dgeo[g, 3]),
                     ftype(dgeo[g, 4]), ftype(dgeo[g, 5]), ftype(dgeo[g, 6]), ftype(dgeo[g, 7]),
                     ftype(dgeo[g, 8]))
                sb = st[blk:blk + stride]
                jx = ftype(x0 + h * lanes)
                for lane in range(lanes):
                    _lane_tangent(sb, lane, lanes, jx, lane_f[lane], u_f, a_f, b_f, c_f, dy_f, pc_f,
                                  c0_f, c1_f, A_f, f0, f1, f2, f3, d, kf, mf, kc, ks)
            elif smooth:
                pc_f, A_f, c0_f, c1_f, _u0, _q0, _q1 = _smooth_values(geo, g, ftype)
                _segment_forward_smooth(st[blk:blk + stride], at, pair, ftype(x0 + h * lanes), u_f,
                                        a_f, b_f, c_f, dy_f, pc_f, c0_f, c1_f, A_f, f0, f1, f2, f3,
                                        kf, mf, lanes, lane_f, kc, ks)
            else:
                _segment_forward(st[blk:blk + stride], at, pair, ftype(x0 + h * lanes), u_f, a_f,
                                 b_f, c_f, dy_f, lpm_f, o_f, f0, f1, f2, f3, kf, mf, lanes, lane_f,
                                 kc)


def _make_forward(ftype, lanes: int, smooth: bool = False, two_orders: bool = False,
                  tangent: bool = False):
    """The forward compositing kernel computing in ``ftype`` with segments of
    ``lanes`` pixels (one AVX-512 register: 8 float64 or 16 float32), with the
    cut window or (``smooth``) the smooth one. Per-Gaussian
    set-up, row ranges and the segments reached stay float64; the per-pixel
    tests and compositing run in ``ftype``.

    Two depth orders at once (issue 67's cross-fade; ``two_orders``, a kernel
    of its own, as each inlined copy of the compositing compiles anew): the
    kernel takes a second list ``gids_b`` with the same members per tile in
    another order, and a weight ``s_blend``; a tile whose two lists differ is composited in
    both (two pixel states; where both lists hold the same Gaussian at the
    same position, its alphas are computed once for both) and written as
    out_a + s_blend (out_b - out_a), the same bits as two separate renders
    blended so; ``gids`` twice is a plain render.

    The tangent pass (``tangent``, smooth window, one order: a kernel of its
    own): the kernel takes the Gaussians' rates ``dgeo`` (N, 9: du, dv, d
    conic a, b, c, d features 0..3, per unit time) and writes the image's
    derivative into ``dout`` beside the image, which has the same bits as
    the plain render's (:func:`_lane_tangent`).

    The kernel is a closure over plain values only (type, ints, constants,
    arrays): numba's on-disk cache keys a closure by its values, and a
    dispatcher among them would pickle differently in every process."""
    zero, one, half = ftype(0.0), ftype(1.0), ftype(0.5)
    kc = (zero, one, half, ftype(ALPHA_MAX), ftype(ALPHA_MIN), ftype(T_MIN), ftype(POWER_MIN))
    ks = (ftype(2.0), ftype(3.0), ftype(1.0 / T_MIN))
    # segment block: 6 fields x lanes (T, features 0..3, stop index); the
    # tangent's 5 more (dT, d features 0..3)
    FT, FL = 0, 5 * lanes
    FBLK = (11 if tangent else 6) * lanes
    lane_f = np.arange(lanes).astype(ftype)  # exact: no per-segment int conversion
    per_segment = lanes < 16  # tile rows of 16 hold several segments: find each

    @njit(parallel=True, cache=True, fastmath=False)
    def kernel(tile_ids, offsets, gids, means2d, conics, opac, feats, bg, width, height, tile,
               out, out_T, n_contrib, order, bounds, gids_b=None, s_blend=0.0, dgeo=None,
               dout=None):
        tiles_x = (width + tile - 1) // tile
        C = feats.shape[1]
        nseg = (tile + lanes - 1) // lanes
        geo = _prepare_gaussians(means2d, conics, opac, feats, smooth)
        sb = ftype(s_blend)
        for w in prange(bounds.shape[0] - 1):
            for r in range(bounds[w], bounds[w + 1]):
                si = order[r]
                x0, y0, tw, th = _tile_origin(tile_ids[si], tiles_x, tile, width, height)
                start = offsets[si]
                m = offsets[si + 1] - start
                mf = ftype(m)
                pair = False
                if two_orders:
                    for k in range(m):
                        if gids[start + k] != gids_b[start + k]:
                            pair = True
                            break
                # one block per (row, segment), holding each state's values (two in a
                # tile whose orders differ): lanes past the tile's width start closed
                ns = 2 if pair else 1
                st = np.zeros(th * nseg * ns * FBLK, dtype=ftype)
                reached = np.zeros(th * nseg, dtype=np.bool_)
                for ii in range(th):
                    for jj in range(nseg * lanes):
                        for q in range(ns):
                            blk = ((ii * nseg + jj // lanes) * ns + q) * FBLK
                            st[blk + FT + jj % lanes] = one
                            st[blk + FL + jj % lanes] = mf if jj < tw else -one
                if tangent:  # a constant: numba compiles one of the branches
                    for k in range(m):
                        _composite_gaussian(geo, gids[start + k], ftype(k), st, 0, False, 1, reached,
                                            x0, y0, tw, th, mf, smooth, ftype, lanes, nseg,
                                            per_segment, FBLK, FL, lane_f, kc, ks, True, dgeo)
                elif not two_orders:
                    for k in range(m):
                        _composite_gaussian(geo, gids[start + k], ftype(k), st, 0, False, 1, reached,
                                            x0, y0, tw, th, mf, smooth, ftype, lanes, nseg,
                                            per_segment, FBLK, FL, lane_f, kc, ks, False, geo)
                else:
                    for k in range(m):
                        g = gids[start + k]
                        g2 = gids_b[start + k]
                        # the same Gaussian at the same position: its alphas once, into
                        # both states; else each list's Gaussian into its own state
                        # (one call site: each inlined copy of it is compiled anew)
                        for q in range(1 if g == g2 else 2):
                            _composite_gaussian(geo, g2 if q == 1 else g, ftype(k), st, q * FBLK,
                                                pair and g == g2, ns, reached, x0, y0, tw, th, mf,
                                                smooth, ftype, lanes, nseg, per_segment, FBLK, FL,
                                                lane_f, kc, ks, False, geo)
                for ii in range(th):
                    for jj in range(tw):
                        blk = (ii * nseg + jj // lanes) * ns * FBLK
                        lane = jj % lanes
                        T = st[blk + FT + lane]
                        for ch in range(C):
                            va = _mul_add(T, ftype(bg[ch]), st[blk + lanes * (1 + ch) + lane])
                            if pair:
                                b2 = blk + FBLK
                                vb = _mul_add(st[b2 + FT + lane], ftype(bg[ch]),
                                              st[b2 + lanes * (1 + ch) + lane])
                                va = va + sb * (vb - va)
                            out[y0 + ii, x0 + jj, ch] = va
                            if tangent:
                                dout[y0 + ii, x0 + jj, ch] = (st[blk + 6 * lanes + lane] * bg[ch]
                                                              + st[blk + lanes * (7 + ch) + lane])
                        out_T[y0 + ii, x0 + jj] = T
                        n_contrib[y0 + ii, x0 + jj] = int(st[blk + FL + lane])

    kernel.__doc__ = """Composite the tiles ``tile_ids`` (row-major tile numbers), computing in
    %s; the list of tile_ids[s] is gids[offsets[s]:offsets[s + 1]] (and in a
    second depth order gids_b[...], cross-faded by s_blend: :func:`_make_forward`).
    out (H,W,C), C <= 4, out_T (H,W) final transmittance, n_contrib (H,W) =
    number of list entries processed (the backward walks [0, n_contrib); both
    of the first order); pixels of other tiles are untouched. Thread w renders
    positions order[bounds[w]:bounds[w + 1]] of tile_ids
    (:func:`tile_schedule`).""" % np.dtype(ftype).name
    return kernel


LANES_F32 = 16  # float32 pixels per segment: one AVX-512 register
F32_MAX_LIST = 1 << 24  # float32 holds list positions exactly up to here
raster_forward_kernel = _make_forward(np.float64, LANES)
raster_forward_kernel_f32 = _make_forward(np.float32, LANES_F32)
raster_forward_kernel_smooth = _make_forward(np.float64, LANES, smooth=True)
raster_forward_kernel_f32_smooth = _make_forward(np.float32, LANES_F32, smooth=True)
raster_tangent_kernel = _make_forward(np.float64, LANES, smooth=True, tangent=True)
_BLEND_KERNELS = {(np.dtype(dt), smooth): _make_forward(dt, lanes, smooth, two_orders=True)
                  for dt, lanes in ((np.float64, LANES), (np.float32, LANES_F32))
                  for smooth in (False, True)}


def check_window(window: str) -> str:
    """``window`` if it is one of :data:`WINDOWS`; else ValueError."""
    if window not in WINDOWS:
        raise ValueError(f"window must be one of {', '.join(WINDOWS)}, got {window!r}")
    return window


def forward_kernel(compute_dtype, offsets: np.ndarray, window: str = "cut", two_orders: bool = False):
    """The forward kernel computing in ``compute_dtype``: float32 (16 lanes,
    for renders that no backward pass follows) or float64 (8 lanes; the
    backward recomputes in float64, so a forward it follows computes so too),
    with ``window`` (:data:`WINDOWS`); with ``two_orders``, the kernel that
    composites two depth orders and cross-fades them (:func:`_make_forward`).
    float32 falls back to float64 for a tile list longer than float32 counts
    exactly (2^24 entries)."""
    smooth = check_window(window) == "smooth"
    f32 = np.dtype(compute_dtype) == np.float32 and (
        offsets.shape[0] < 2 or int(np.diff(offsets).max()) < F32_MAX_LIST)
    if two_orders:
        return _BLEND_KERNELS[(np.dtype(np.float32 if f32 else np.float64), smooth)]
    if f32:
        return raster_forward_kernel_f32_smooth if smooth else raster_forward_kernel_f32
    return raster_forward_kernel_smooth if smooth else raster_forward_kernel


# backward segment block, ``lanes`` values each: pixel state T, T_final, g_T,
# S (sum behind of w f.g), g_out[0..4), stop index; then the current pair's
# gradient terms d u, d v, d conic a, b, c, d opacity, d feats[0..4)
_NGRAD = 6 + MAX_CHANNELS


def _backward_layout(lanes: int) -> tuple:
    """(T, T_final, g_T, S, g_out, stop, acc) offsets and block size of a
    backward segment block of ``lanes`` lanes."""
    L = lanes
    return (0, L, 2 * L, 3 * L, 4 * L, 8 * L, 9 * L), 9 * L + _NGRAD * L


@njit(inline="always", fastmath=False)
def _store_shape_grads(s, BACC, L, lane, ok, gp, dx, dy, a, b, c, half, zero):
    """A pair's gradient terms in the 2D centre and the conic from dL/dpower
    ``gp`` (where ``ok``, else 0), into the block's accumulators."""
    s[BACC + lane] = _select(ok, -(gp * (a * dx + b * dy)), zero)
    s[BACC + L + lane] = _select(ok, -(gp * (b * dx + c * dy)), zero)
    s[BACC + 2 * L + lane] = _select(ok, -(half * gp * dx * dx), zero)
    s[BACC + 3 * L + lane] = _select(ok, -(gp * dx * dy), zero)
    s[BACC + 4 * L + lane] = _select(ok, -(half * gp * dy * dy), zero)


@njit(inline="always", fastmath=False)
def _segment_backward(s, jx, u, a, b, c, dy, lpm, o, f0, f1, f2, f3, kf, lanes, lane_f, kc,
                      lay):
    """Undo Gaussian k over one segment block (back to front) and add its
    per-lane gradient partial sums into the block's accumulators. Arguments as
    :func:`_segment_forward`'s, in the same float type, and the block layout
    ``lay`` (:func:`_backward_layout`); power, exp and alpha are the
    forward's, operation for operation, so the same pixels take part."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    BT, BTF, BGT, BS, BG, BL, BACC = lay
    L = lanes
    for lane in range(lanes):
        dx = u - ((jx + lane_f[lane]) + half)
        power = _mul_add(-(b * dx), dy, -half * _mul_add(a * dx, dx, c * dy * dy))
        ok = (power <= zero) & (power >= lpm) & (power >= p_min) & (kf < s[BL + lane])
        G = _exp_neg_any(_select(ok, power, zero))
        a_raw = o * G
        alpha = min(a_max, a_raw)
        ok = ok & (alpha >= a_min)
        inv_om = one / (one - alpha)
        T = s[BT + lane] * inv_om  # transmittance in front of this Gaussian
        w = alpha * T
        g0 = s[BG + lane]
        g1 = s[BG + L + lane]
        g2 = s[BG + 2 * L + lane]
        g3 = s[BG + 3 * L + lane]
        dotf = g0 * f0 + g1 * f1 + g2 * f2 + g3 * f3
        # dL/dalpha = T f.g - (sum_{behind} w_j f_j.g + gT T_final) / (1 - alpha)
        g_alpha = T * dotf - (s[BS + lane] + s[BGT + lane] * s[BTF + lane]) * inv_om
        # as in _segment_forward: no select against the loaded value (the same
        # bits: T = s * inv_om; S never -0)
        s[BT + lane] = s[BT + lane] * _select(ok, inv_om, one)
        s[BS + lane] = s[BS + lane] + _select(ok, w * dotf, zero)
        # the pair's terms (one segment call per block and Gaussian: stored, not summed)
        s[BACC + 6 * L + lane] = _select(ok, w * g0, zero)
        s[BACC + 7 * L + lane] = _select(ok, w * g1, zero)
        s[BACC + 8 * L + lane] = _select(ok, w * g2, zero)
        s[BACC + 9 * L + lane] = _select(ok, w * g3, zero)
        ok = ok & (a_raw <= a_max)  # clamped: no gradient to opacity or shape
        gp = alpha * g_alpha  # dL/dpower
        s[BACC + 5 * L + lane] = _select(ok, G * g_alpha, zero)
        _store_shape_grads(s, BACC, L, lane, ok, gp, dx, dy, a, b, c, half, zero)


@njit(inline="always", fastmath=False)
def _lane_backward_smooth(s, lane, jx, u, a, b, c, dy, pc, c0, c1, u0, q0, q1, o, f0, f1, f2, f3,
                          kf, lanes, lane_f, kc, ks, lay, flat):
    """One lane of :func:`_segment_backward_smooth`; ``flat`` (a constant at
    each call site): the block's weights are not faded (r = 1, r' = 0), so
    the fade's terms are left out; the same bits as with them."""
    zero, one, half, a_max, a_min, t_min, p_min = kc
    two, three, inv_t_min, t_flat = ks
    BT, BTF, BGT, BS, BG, BL, BACC = lay
    L = lanes
    dx = u - ((jx + lane_f[lane]) + half)
    power = _mul_add(-(b * dx), dy, -half * _mul_add(a * dx, dx, c * dy * dy))
    ok = (power <= zero) & (power >= pc) & (kf < s[BL + lane])
    G = _exp_neg_any(min(max(power, p_min), zero))
    a_raw = _mul_add(o, G, -_mul_add(c1, power, c0))
    alpha = min(a_max, max(zero, a_raw))
    inv_om = one / (one - alpha)
    T = s[BT + lane] * inv_om  # transmittance in front of this Gaussian
    g0 = s[BG + lane]
    g1 = s[BG + L + lane]
    g2 = s[BG + 2 * L + lane]
    g3 = s[BG + 3 * L + lane]
    dotf = g0 * f0 + g1 * f1 + g2 * f2 + g3 * f3
    if flat:  # r = 1, r' = 0: T r = T, alpha T (r + T r') = alpha T, to the bit
        w = alpha * T
        g_alpha = T * dotf - (s[BS + lane] + s[BGT + lane] * s[BTF + lane]) * inv_om
        behind = w * dotf
    else:
        r, dr = _ramp(T, t_min, inv_t_min, zero, one, two, three)
        Tr = T * r
        w = alpha * Tr
        g_alpha = Tr * dotf - (s[BS + lane] + s[BGT + lane] * s[BTF + lane]) * inv_om
        behind = alpha * T * (r + T * dr) * dotf
    s[BT + lane] = s[BT + lane] * _select(ok, inv_om, one)
    s[BS + lane] = s[BS + lane] + _select(ok, behind, zero)
    s[BACC + 6 * L + lane] = _select(ok, w * g0, zero)
    s[BACC + 7 * L + lane] = _select(ok, w * g1, zero)
    s[BACC + 8 * L + lane] = _select(ok, w * g2, zero)
    s[BACC + 9 * L + lane] = _select(ok, w * g3, zero)
    ok = ok & (a_raw <= a_max) & (a_raw >= zero)  # clamped: no gradient to opacity or shape
    gp = (o * G - c1) * g_alpha  # dL/dpower
    s[BACC + 5 * L + lane] = _select(ok, (u0 * G - _mul_add(q1, power, q0)) * g_alpha, zero)
    _store_shape_grads(s, BACC, L, lane, ok, gp, dx, dy, a, b, c, half, zero)


@njit(inline="always", fastmath=False)
def _segment_backward_smooth(s, jx, u, a, b, c, dy, pc, c0, c1, u0, q0, q1, o, f0, f1, f2, f3, kf,
                             lanes, lane_f, kc, ks, lay):
    """:func:`_segment_backward` for :func:`_segment_forward_smooth` (the
    module docstring's gradients; ``o``: the Gaussian's A): same block
    layout, the sum behind a pixel S holding alpha T (r + T r') f.g. Where
    every lane that has not stopped before this Gaussian (kf < its stop
    index, reached or not) has T >= ``t_flat`` behind it (3 T_MIN; so in
    front of it too), r = 1 and r' = 0 in the whole block:
    most blocks, as T falls under 2 T_MIN only at a pixel's last Gaussians."""
    BT, BL = lay[0], lay[5]
    t_flat = ks[3]
    flat = True
    for lane in range(lanes):
        flat &= (kf >= s[BL + lane]) | (s[BT + lane] >= t_flat)
    if flat:
        for lane in range(lanes):
            _lane_backward_smooth(s, lane, jx, u, a, b, c, dy, pc, c0, c1, u0, q0, q1, o, f0, f1, f2,
                                  f3, kf, lanes, lane_f, kc, ks, lay, True)
    else:
        for lane in range(lanes):
            _lane_backward_smooth(s, lane, jx, u, a, b, c, dy, pc, c0, c1, u0, q0, q1, o, f0, f1, f2,
                                  f3, kf, lanes, lane_f, kc, ks, lay, False)


@njit(inline="always", fastmath=False)
def _add_block(acc, s, n):
    """acc[:n] += s[:n] (a slice: the loop over a plain offset did not
    vectorise and cost the backward 1.4x)."""
    for z in range(n):
        acc[z] += s[z]


def _make_backward(ftype, lanes: int, smooth: bool = False):
    """The backward compositing kernel computing in ``ftype`` with segments of
    ``lanes`` pixels, following the forward kernel of the same type and
    window (a closure over plain values, as :func:`_make_forward`)."""
    zero, one, half = ftype(0.0), ftype(1.0), ftype(0.5)
    kc = (zero, one, half, ftype(ALPHA_MAX), ftype(ALPHA_MIN), ftype(T_MIN), ftype(POWER_MIN))
    # and the T above which the fade is 1 (_segment_backward_smooth)
    ks = (ftype(2.0), ftype(3.0), ftype(1.0 / T_MIN), ftype(3.0 * T_MIN))
    lay, BBLK = _backward_layout(lanes)
    BT, BTF, BGT, BS, BG, BL, BACC = lay
    NACC = _NGRAD * lanes
    lane_f = np.arange(lanes).astype(ftype)
    per_segment = lanes < 16

    @njit(parallel=True, cache=True, fastmath=False)
    def kernel(offsets, gids, means2d, conics, opac, feats, width, height, tile, out_T,
               n_contrib, g_out, g_T, pair_grad, order, bounds):
        tiles_x = (width + tile - 1) // tile
        C = feats.shape[1]
        nseg = (tile + lanes - 1) // lanes
        geo = _prepare_gaussians(means2d, conics, opac, feats, smooth)
        for w in prange(bounds.shape[0] - 1):
            for r in range(bounds[w], bounds[w + 1]):
                t = order[r]
                x0, y0, tw, th = _tile_origin(t, tiles_x, tile, width, height)
                start = offsets[t]
                m = offsets[t + 1] - start
                st = np.zeros(th * nseg * BBLK, dtype=ftype)
                reached = np.zeros(th * nseg, dtype=np.bool_)
                for ii in range(th):
                    for jj in range(nseg * lanes):
                        blk = (ii * nseg + jj // lanes) * BBLK
                        lane = jj % lanes
                        if jj < tw:
                            st[blk + BT + lane] = out_T[y0 + ii, x0 + jj]
                            st[blk + BTF + lane] = out_T[y0 + ii, x0 + jj]
                            st[blk + BGT + lane] = g_T[y0 + ii, x0 + jj]
                            for ch in range(C):
                                st[blk + BG + lanes * ch + lane] = g_out[y0 + ii, x0 + jj, ch]
                            st[blk + BL + lane] = n_contrib[y0 + ii, x0 + jj]
                        else:
                            st[blk + BT + lane] = one
                            st[blk + BTF + lane] = one
                            st[blk + BL + lane] = -one  # closed
                # a block takes part in Gaussian k only if one of its pixels stops after k
                last = np.empty(th * nseg, dtype=ftype)
                for q in range(th * nseg):
                    mx = -one
                    for lane in range(lanes):
                        mx = max(mx, st[q * BBLK + BL + lane])
                    last[q] = mx
                acc = np.empty(NACC, dtype=ftype)
                touched = np.empty(th * nseg, dtype=np.int64)
                for k in range(m - 1, -1, -1):
                    g = gids[start + k]
                    for ch in range(6 + C):
                        pair_grad[start + k, ch] = 0.0
                    lpm = geo[g, 4]
                    if lpm > 0.0:
                        continue
                    a, b, m2, det, u, v = geo[g, 1], geo[g, 2], geo[g, 5], geo[g, 6], geo[g, 7], geo[g, 8]
                    inv_a = geo[g, 14]
                    o_f, a_f, b_f, c_f, lpm_f, u_f, v_f, f0, f1, f2, f3 = _segment_values(geo, g, ftype)
                    kf = ftype(k)
                    n_touched = 0
                    i_lo, i_hi = _rows_of(v, geo[g, 13], y0, th)
                    _rows_reached(reached, i_lo, i_hi, u, v, a, b, det, m2, inv_a, x0, y0, tw, lanes,
                                  nseg, per_segment)
                    for ii in range(i_lo, i_hi + 1):
                        h_lo, h_hi = _row_segments(reached, ii, u, v, a, b, det, m2, inv_a, x0, y0, tw,
                                                   lanes, nseg, per_segment)
                        if h_lo > h_hi:
                            continue
                        dy_f = v_f - (ftype(y0 + ii) + half)
                        for h in range(h_lo, h_hi + 1):
                            if kf >= last[ii * nseg + h]:
                                continue
                            blk = (ii * nseg + h) * BBLK
                            if smooth:
                                pc_f, A_f, c0_f, c1_f, u0_f, q0_f, q1_f = _smooth_values(geo, g, ftype)
                                _segment_backward_smooth(st[blk:blk + BBLK], ftype(x0 + h * lanes), u_f,
                                                         a_f, b_f, c_f, dy_f, pc_f, c0_f, c1_f, u0_f,
                                                         q0_f, q1_f, A_f, f0, f1, f2, f3, kf, lanes,
                                                         lane_f, kc, ks, lay)
                            else:
                                _segment_backward(st[blk:blk + BBLK], ftype(x0 + h * lanes), u_f, a_f,
                                                  b_f, c_f, dy_f, lpm_f, o_f, f0, f1, f2, f3, kf,
                                                  lanes, lane_f, kc, lay)
                            touched[n_touched] = blk
                            n_touched += 1
                    if n_touched == 0:
                        continue
                    acc[:] = zero
                    for q in range(n_touched):  # acc += the block's terms for this Gaussian
                        _add_block(acc, st[touched[q] + BACC:touched[q] + BACC + NACC], NACC)
                    for f in range(6 + C):
                        total = 0.0
                        for lane in range(lanes):
                            total += acc[f * lanes + lane]
                        pair_grad[start + k, f] = total

    kernel.__doc__ = """Per-pair gradients, computing in %s. pair_grad (n_pairs, 6 + C)
    float64 rows: d u, d v, d conic_a, d conic_b, d conic_c, d opacity, d feats[0..C)
    (per pair: lane sums in row order, then the lanes in order). Thread w
    handles tiles order[bounds[w]:bounds[w + 1]] (:func:`tile_schedule`).""" % np.dtype(ftype).name
    return kernel


raster_backward_kernel = _make_backward(np.float64, LANES)
raster_backward_kernel_f32 = _make_backward(np.float32, LANES_F32)
raster_backward_kernel_smooth = _make_backward(np.float64, LANES, smooth=True)
raster_backward_kernel_f32_smooth = _make_backward(np.float32, LANES_F32, smooth=True)


def backward_kernel(compute_dtype, offsets: np.ndarray, window: str = "cut"):
    """The backward kernel following :func:`forward_kernel`'s choice for the
    same ``compute_dtype``, lists and ``window``."""
    fwd = forward_kernel(compute_dtype, offsets, window)
    if fwd is raster_forward_kernel_f32:
        return raster_backward_kernel_f32
    if fwd is raster_forward_kernel_f32_smooth:
        return raster_backward_kernel_f32_smooth
    return raster_backward_kernel_smooth if window == "smooth" else raster_backward_kernel


@njit(cache=True, fastmath=False)
def reduce_pairs_kernel(gids, pair_grad, out):
    """out[g] += pair_grad[p] for every pair p of Gaussian g, in pair order."""
    for p in range(gids.shape[0]):
        g = gids[p]
        for c in range(pair_grad.shape[1]):
            out[g, c] += pair_grad[p, c]


def bin_gaussians(means2d, depths, radii, width, height, tile=16, opac=None):
    """Tile lists sorted by depth. Returns (offsets (n_tiles+1,), gids (n_pairs,)).

    radii (N,) are the 3-sigma radii (0 = culled). With ``opac`` (N,) the box
    shrinks to where alpha can reach 1/255 (fewer tile pairs, same image: the
    per-pixel tests are exact); Gaussians with opacity < 1/255 are dropped.
    """
    r = radii.astype(np.float64)
    if opac is not None:
        o = np.asarray(opac, dtype=np.float64)
        with np.errstate(divide="ignore"):
            m2 = np.clip(2.0 * np.log(np.maximum(o, 1e-300) / ALPHA_MIN), 0.0, 9.0)
        r = np.where(o >= ALPHA_MIN, r * np.sqrt(m2 / 9.0) * (1.0 + 1e-6) + 1e-3, 0.0)
        r[radii <= 0] = 0.0
    order = depth_order(r > 0, depths)
    return bin_kernel(order, means2d, r, int(width), int(height), int(tile), numba.get_num_threads())


def depth_order(visible: np.ndarray, depths: np.ndarray, prev: np.ndarray | None = None) -> np.ndarray:
    """(m,) int64: the Gaussians with ``visible`` (N,) bool by increasing
    depth, ties by index (the order of every tile list). With ``prev``, the
    order at a nearby pose, an insertion sort from there
    (:func:`resort_by_depth`), else, or when that needs more than 4N moves, a
    stable argsort: the same order either way."""
    if prev is not None:
        order, ok = resort_by_depth(prev, visible, depths, 4 * visible.shape[0])
        if ok:
            return order
    vis = np.flatnonzero(visible)
    return vis[np.argsort(depths[vis], kind="stable")].astype(np.int64)


def _channels(feats) -> int:
    C = int(feats.shape[1])
    if not 1 <= C <= MAX_CHANNELS:
        raise ValueError(f"the compositing kernels take 1 to {MAX_CHANNELS} feature channels, got {C}")
    return C


def rasterize_forward(means2d, conics, opac, feats, bg, width, height, offsets, gids, tile=16,
                      compute_dtype=np.float64, window="cut"):
    """Composite features front to back.

    Parameters
    ----------
    means2d (N,2) px; conics (N,3); opac (N,) in [0,1]; feats (N,C), 1 <= C <= 4;
    bg (C,); all of one float dtype (float32 or float64), which the outputs take.
    compute_dtype : float64 (what :func:`rasterize_backward` recomputes in) or
        float32 (~1.25x faster, for renders no backward follows;
        :func:`forward_kernel`).
    window : 'cut' (3DGS's) or 'smooth' (continuous in the Gaussians'
        positions and shapes: module docstring).

    Returns
    -------
    out (H,W,C) composited features incl. background, out_T (H,W) final
    transmittance, n_contrib (H,W) int32.
    """
    dt = feats.dtype
    C = _channels(feats)
    out = np.empty((height, width, C), dtype=dt)
    out_T = np.empty((height, width), dtype=dt)
    n_contrib = np.empty((height, width), dtype=np.int32)
    n_tiles = ((int(width) + tile - 1) // tile) * ((int(height) + tile - 1) // tile)
    forward_kernel(compute_dtype, offsets, window)(
        np.arange(n_tiles, dtype=np.int64), offsets, gids, means2d, conics, opac, feats, bg,
        int(width), int(height), int(tile), out, out_T, n_contrib, *tile_schedule(offsets))
    return out, out_T, n_contrib


def rasterize_backward(means2d, conics, opac, feats, width, height, offsets, gids,
                       out_T, n_contrib, g_out, g_T, tile=16, compute_dtype=np.float64,
                       window="cut"):
    """Backward of :func:`rasterize_forward` (computing in the forward's
    ``compute_dtype`` and ``window``: the backward recomputes its power, exp
    and alpha).

    g_out (H,W,C) gradient of ``out``; g_T (H,W) gradient of the final
    transmittance (the background term is added by the caller).

    Returns float64 (N, 6 + C): d u, d v, d conic a, b, c, d opacity, d feats.
    """
    n = means2d.shape[0]
    C = _channels(feats)
    pair_grad = np.empty((gids.shape[0], 6 + C), dtype=np.float64)
    backward_kernel(compute_dtype, offsets, window)(
        offsets, gids, means2d, conics, opac, feats, int(width), int(height), int(tile), out_T,
        n_contrib, g_out, g_T, pair_grad, *tile_schedule(offsets))
    grads = np.zeros((n, 6 + C), dtype=np.float64)
    reduce_pairs_kernel(gids, pair_grad, grads)
    return grads
