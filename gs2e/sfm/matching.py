"""SIFT descriptor matching between views: COLMAP's brute-force rule, as GEMMs.

COLMAP's CPU matcher searches a per-view faiss index (IVF, 4 of ``4 sqrt(n)``
lists probed: approximate, and each index is trained by k-means first); its
exact brute-force option computes the dot products with scalar integer loops
(11x slower on mouse_colmap). Here the dot products of the uint8 RootSIFT
descriptors are float32 GEMMs of one view against a chunk of its partner
views, then one compiled pass over each block finds the two largest dot
products of every row and column. The products are integers below
128 * 255^2 < 2^24, so float32 holds them exactly whatever the summation order:
the matches do not depend on the BLAS, the instruction set or the thread count.

``sfm.descriptor_matcher: gemm`` (not the default): on mouse_colmap's 1,540
view pairs it takes about half the descriptor-matching CPU of COLMAP's index
(5.3-6.8 against 10.4 CPU-s, AVX-512). With one camera per view size it
registers the same views as the index on five captures, at 0.8-1.03x the CPU
of the whole SfM: too little to change the default (docs/sfm.md).

The rule is COLMAP's brute force (``FindBestMatchesBruteForce``), so the matches
equal those of ``SiftMatchingOptions.cpu_brute_force_matcher`` (tests/test_sfm_matching.py):

- a feature's best partner is the largest dot product (the first on ties),
  its second the next largest value (equal to the best on a tie), both at
  least 0;
- the angles ``acos(dot / 512^2)`` (rad) of best and second, in float32 by
  libm's ``acosf`` as COLMAP's ``std::acos`` on a float (numpy's float32
  arccos differs from it in the last bit for a third of the dot products),
  must satisfy ``best <= max_distance`` and ``best < max_ratio * second``;
- with ``cross_check`` a match is kept only when each feature is the other's
  best partner.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

SQ_DESCRIPTOR_NORM = 512.0 * 512.0  # squared norm of a RootSIFT descriptor in COLMAP's uint8 scale
# dot-product blocks of one view against a chunk of partners: at most this many
# float32 values (64 MB), and chunks of views of similar feature counts (little padding)
BLOCK_VALUES = 16 * 1024 * 1024
_LANES = 16  # independent running maxima per row (SIMD lanes; 16 float32 = one AVX-512 register, two AVX2)


@njit(cache=True, nogil=True)
def best_two(dots, row_best, row_second, row_idx, col_best, col_second, col_idx):
    """The two largest dot products of every row and column of each block.

    Parameters
    ----------
    dots : (K, N1, M) float32, K blocks of dot products (>= 0).
    row_best, row_second : (K, N1) float32 outputs: per row the largest value
        and the next largest (the largest again on a tie), floored at 0.
    row_idx : (K, N1) int32 output: column of the largest (the first on a
        tie), -1 where every value is 0.
    col_best, col_second, col_idx : (K, M) outputs, the same per column.

    Each row is read twice: once into ``_LANES`` independent running maxima
    (vectorised), merged in column order at the end, once into the columns'
    running top two (two loops: fused into one, neither vectorises and the
    kernel is 4x slower).
    About 0.7 ns per dot product on one core, as fast in code for AVX2 as for
    AVX-512. Releases the GIL.
    """
    K, n1, m = dots.shape
    for k in range(K):
        lane_best = np.zeros(_LANES, np.float32)
        lane_second = np.zeros(_LANES, np.float32)
        lane_idx = np.full(_LANES, -1, np.int32)
        cb, cs, ci = col_best[k], col_second[k], col_idx[k]
        cb[:] = 0.0
        cs[:] = 0.0
        ci[:] = -1
        for r in range(n1):
            row = dots[k, r]
            lane_best[:] = 0.0
            lane_second[:] = 0.0
            lane_idx[:] = -1
            full = m - m % _LANES
            for c0 in range(0, full, _LANES):
                for lane in range(_LANES):
                    x = row[c0 + lane]
                    old = lane_best[lane]
                    lane_second[lane] = max(lane_second[lane], min(old, x))
                    lane_idx[lane] = c0 + lane if x > old else lane_idx[lane]
                    lane_best[lane] = max(old, x)
            for c in range(full, m):
                x = row[c]
                old = lane_best[c - full]
                lane_second[c - full] = max(lane_second[c - full], min(old, x))
                lane_idx[c - full] = c if x > old else lane_idx[c - full]
                lane_best[c - full] = max(old, x)
            # the columns' running top two over the rows so far (a separate
            # loop: fused with the one above, neither vectorises)
            for c in range(m):
                x = row[c]
                old = cb[c]
                cs[c] = max(cs[c], min(old, x))
                ci[c] = r if x > old else ci[c]
                cb[c] = max(old, x)
            best = np.float32(0.0)
            idx = -1
            for lane in range(_LANES):
                v = lane_best[lane]
                if v > best or (v == best and v > 0.0 and lane_idx[lane] < idx):
                    best = v
                    idx = lane_idx[lane]
            second = np.float32(0.0)
            for lane in range(_LANES):
                second = max(second, lane_second[lane])
                if lane_idx[lane] != idx:
                    second = max(second, lane_best[lane])
            row_best[k, r] = best
            row_second[k, r] = second
            row_idx[k, r] = idx


_DOT_ONE = int(SQ_DESCRIPTOR_NORM)  # dot products from here on have angle 0


@njit(cache=True)
def _angles(n: int) -> np.ndarray:
    """(n,) float32: acos(min(d / 512^2, 1)) for the integers d = 0 .. n - 1,
    in float32 arithmetic (numba's math.acos of a float32 is libm's acosf)."""
    out = np.empty(n, np.float32)
    inv = np.float32(1.0 / SQ_DESCRIPTOR_NORM)
    for d in range(n):
        out[d] = math.acos(min(inv * np.float32(d), np.float32(1.0)))
    return out


@functools.lru_cache(maxsize=1)
def angle_table() -> np.ndarray:
    """(2^18 + 1,) float32: the angle (rad) of every dot product 0 .. 512^2
    (larger ones have angle 0), as COLMAP computes it."""
    return _angles(_DOT_ONE + 1)


def passes(best_dot: np.ndarray, second_dot: np.ndarray, max_ratio: float, max_distance: float) -> np.ndarray:
    """COLMAP's distance and ratio tests.

    Parameters
    ----------
    best_dot, second_dot : (N,) float32, each feature's largest and second
        largest dot product (integers >= 0, COLMAP's uint8 descriptor scale).
    max_ratio : the ratio test's bound on best / second angle.
    max_distance : the best angle's bound (rad).

    Returns
    -------
    (N,) bool: the feature's best partner is a match candidate.
    """
    table = angle_table()
    best = table[np.minimum(best_dot, _DOT_ONE).astype(np.int64)]
    second = table[np.minimum(second_dot, _DOT_ONE).astype(np.int64)]
    return (best_dot > 0) & (best <= np.float32(max_distance)) & (best < np.float32(max_ratio) * second)


def _matches(rb, rs, ri, cb, cs, ci, max_ratio: float, max_distance: float, cross_check: bool) -> np.ndarray:
    """Matches with one partner of a block, from :func:`best_two`'s outputs for
    it: ``rb``, ``rs``, ``ri`` (N1,) of the view's features, ``cb``, ``cs``,
    ``ci`` (M,) of the partner's (padded; a candidate's best partner is never
    a padding column, whose dot products are 0). Returns (K, 2) uint32
    feature indices (view, partner)."""
    rows = np.flatnonzero(passes(rb, rs, max_ratio, max_distance))
    cols = ri[rows]
    if cross_check:
        keep = passes(cb[cols], cs[cols], max_ratio, max_distance) & (ci[cols] == rows)
        rows, cols = rows[keep], cols[keep]
    return np.column_stack([rows, cols]).astype(np.uint32)


def _match_one_view(a: np.ndarray, partners: list[np.ndarray], max_ratio: float, max_distance: float,
                    cross_check: bool, block_values: int) -> list[np.ndarray]:
    """Matches of view descriptors ``a`` (N, 128) uint8 with each of ``partners``
    (all non-empty), in their order: GEMMs of ``a`` against chunks of partners
    of similar feature counts, each chunk padded with zero descriptors (a dot
    product of 0 is never a best partner, and COLMAP's second best starts at 0)."""
    order = sorted(range(len(partners)), key=lambda q: -len(partners[q]))
    a = a.astype(np.float32)
    out: list[np.ndarray] = [np.zeros((0, 2), np.uint32)] * len(partners)
    start = 0
    while start < len(order):
        m = len(partners[order[start]])
        k = max(1, min(len(order) - start, block_values // (len(a) * m)))
        chunk = order[start:start + k]
        start += k
        b = np.zeros((k, m, 128), np.float32)
        for c, q in enumerate(chunk):
            b[c, :len(partners[q])] = partners[q]
        dots = np.matmul(a, b.transpose(0, 2, 1))  # (k, N, m)
        rb, rs, ri = np.empty((k, len(a)), np.float32), np.empty((k, len(a)), np.float32), np.empty((k, len(a)), np.int32)
        cb, cs, ci = np.empty((k, m), np.float32), np.empty((k, m), np.float32), np.empty((k, m), np.int32)
        best_two(dots, rb, rs, ri, cb, cs, ci)
        for c, q in enumerate(chunk):
            out[q] = _matches(rb[c], rs[c], ri[c], cb[c], cs[c], ci[c], max_ratio, max_distance, cross_check)
    return out


def match_views(descriptors: list[np.ndarray], pairs: np.ndarray, max_ratio: float = 0.8,
                max_distance: float = 0.7, cross_check: bool = True, threads: int = 1,
                block_values: int = BLOCK_VALUES) -> list[np.ndarray]:
    """Matches of the view pairs ``pairs``, COLMAP's brute-force rule.

    Parameters
    ----------
    descriptors : per view, (N_v, 128) uint8 RootSIFT descriptors in COLMAP's
        scale (``min(255, round(512 x))``).
    pairs : (P, 2) int view indices into ``descriptors``.
    max_ratio, max_distance, cross_check : COLMAP's ``SiftMatchingOptions``.
    threads : views matched at a time (each on one BLAS thread: the matches do
        not depend on it).
    block_values : most float32 dot products of one view's block (a pair of
        views larger than that is still one block).

    Returns
    -------
    Per pair, (M, 2) uint32 feature indices in its first and second view.
    """
    from concurrent.futures import ThreadPoolExecutor

    from threadpoolctl import threadpool_limits

    from gs2e.common.progress import progress

    desc = [np.asarray(d, np.uint8).reshape(-1, 128) for d in descriptors]
    pairs = np.asarray(pairs, np.int64).reshape(-1, 2)
    out: list[np.ndarray] = [np.zeros((0, 2), np.uint32)] * len(pairs)
    by_view: dict[int, list[int]] = {}
    for p, (i, j) in enumerate(pairs.tolist()):
        if len(desc[i]) and len(desc[j]):
            by_view.setdefault(i, []).append(p)

    def one(i: int) -> None:
        ps = by_view[i]
        for p, m in zip(ps, _match_one_view(desc[i], [desc[pairs[p, 1]] for p in ps], max_ratio,
                                            max_distance, cross_check, block_values)):
            out[p] = m

    with threadpool_limits(1, user_api="blas"), ThreadPoolExecutor(max(1, threads)) as pool:
        for _ in progress(pool.map(one, by_view), total=len(by_view), desc="matching", unit="view"):
            pass
    return out
