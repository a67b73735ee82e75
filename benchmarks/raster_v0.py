"""Baseline for the benchmarks: gs2e's compositing kernels before the
Gaussian-major SIMD rewrite (commit 851db24): pixel-major loops, candidate
lists compacted per row and per 4-pixel segment, libm exp. Same signatures
as :func:`gs2e.splat.raster.raster_forward_kernel` and
:func:`gs2e.splat.raster.raster_backward_kernel`, so a benchmark can swap them
in and time both in one run. Not used by the pipeline."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from gs2e.splat.raster import ALPHA_MAX, ALPHA_MIN, POWER_MIN, T_MIN


CHUNK = 4  # pixels per row segment sharing one candidate list


@njit(cache=True, fastmath=False)
def _extents(la, lb, lc, lo, rx, ry, lpm):
    """Per Gaussian: lpm, the power below which it cannot pass (the 3-sigma cut
    or alpha < 1/255, whichever is tighter, minus a margin), and the half width
    / height (px) of the ellipse power >= lpm, slightly enlarged.

    These only pre-filter; the exact tests still run per pixel, so results do
    not depend on them. Low-opacity Gaussians get much smaller footprints.
    """
    for k in range(la.shape[0]):
        det = la[k] * lc[k] - lb[k] * lb[k]
        if lo[k] < ALPHA_MIN or not det > 0.0:
            lpm[k] = 1.0  # alpha < 1/255 everywhere (or degenerate): never used
            rx[k] = -1.0
            ry[k] = -1.0
            continue
        lpm[k] = max(POWER_MIN, math.log(ALPHA_MIN / lo[k])) - 1e-6
        m2 = -2.0 * lpm[k]  # squared Mahalanobis radius
        # covariance = inverse conic: var_x = c / det, var_y = a / det
        rx[k] = math.sqrt(m2 * lc[k] / det) * (1.0 + 1e-6) + 1e-3
        ry[k] = math.sqrt(m2 * la[k] / det) * (1.0 + 1e-6) + 1e-3


@njit(cache=True, fastmath=False)
def _row_list(lv, lry, py, rl):
    """Indices (in depth order) of tile Gaussians whose ellipse spans row py.
    Branch-free compaction: the test outcome is unpredictable."""
    mr = 0
    for k in range(lv.shape[0]):
        rl[mr] = k
        mr += abs(lv[k] - py) <= lry[k]
    return mr


@njit(cache=True, fastmath=False)
def _seg_list(lu, lrx, rl, mr, x0, x1, sl):
    """Entries of the row list whose ellipse reaches pixel centres in [x0, x1]."""
    ms = 0
    for r in range(mr):
        k = rl[r]
        sl[ms] = k
        ms += (lu[k] + lrx[k] >= x0) and (lu[k] - lrx[k] <= x1)
    return ms


@njit(parallel=True, cache=True, fastmath=False)
def raster_forward_kernel(tile_ids, offsets, gids, means2d, conics, opac, feats, bg,
                          width, height, tile, out, out_T, n_contrib):
    """Composite the tiles ``tile_ids`` (row-major tile numbers); the list of
    tile_ids[s] is gids[offsets[s]:offsets[s + 1]]. out (H,W,C), out_T (H,W)
    final transmittance, n_contrib (H,W) = number of list entries processed
    (the backward walks [0, n_contrib)); pixels of other tiles are untouched."""
    tiles_x = (width + tile - 1) // tile
    C = feats.shape[1]
    for s in prange(tile_ids.shape[0]):
        t = tile_ids[s]
        ty = t // tiles_x
        tx = t - ty * tiles_x
        start = offsets[s]
        m = offsets[s + 1] - start
        # gather this tile's Gaussians contiguously (cache friendly)
        lu = np.empty(m)
        lv = np.empty(m)
        la = np.empty(m)
        lb = np.empty(m)
        lc = np.empty(m)
        lo = np.empty(m)
        lf = np.empty((m, C))
        for k in range(m):
            g = gids[start + k]
            lu[k] = means2d[g, 0]
            lv[k] = means2d[g, 1]
            la[k] = conics[g, 0]
            lb[k] = conics[g, 1]
            lc[k] = conics[g, 2]
            lo[k] = opac[g]
            for c in range(C):
                lf[k, c] = feats[g, c]
        lrx = np.empty(m)
        lry = np.empty(m)
        lpm = np.empty(m)
        _extents(la, lb, lc, lo, lrx, lry, lpm)
        rl = np.empty(m + 1, dtype=np.int64)
        sl = np.empty(m + 1, dtype=np.int64)
        acc = np.empty(C)
        jend = min(width, (tx + 1) * tile)
        for i in range(ty * tile, min(height, (ty + 1) * tile)):
            py = i + 0.5
            mr = _row_list(lv, lry, py, rl)
            for j in range(tx * tile, jend):
                if (j - tx * tile) % CHUNK == 0:
                    ms = _seg_list(lu, lrx, rl, mr, j + 0.5, min(j + CHUNK, jend) - 0.5, sl)
                px = j + 0.5
                T = 1.0
                for c in range(C):
                    acc[c] = 0.0
                last = m
                for r in range(ms):
                    k = sl[r]
                    dx = lu[k] - px
                    dy = lv[k] - py
                    power = -0.5 * (la[k] * dx * dx + lc[k] * dy * dy) - lb[k] * dx * dy
                    if power > 0.0 or power < lpm[k]:
                        continue  # cheap pre-test; the exact tests follow
                    if power < POWER_MIN:
                        continue
                    alpha = min(ALPHA_MAX, lo[k] * math.exp(power))
                    if alpha < ALPHA_MIN:
                        continue
                    t_next = T * (1.0 - alpha)
                    if t_next < T_MIN:
                        last = k
                        break
                    w = alpha * T
                    for c in range(C):
                        acc[c] += lf[k, c] * w
                    T = t_next
                for c in range(C):
                    out[i, j, c] = acc[c] + T * bg[c]
                out_T[i, j] = T
                n_contrib[i, j] = last


@njit(parallel=True, cache=True, fastmath=False)
def raster_backward_kernel(offsets, gids, means2d, conics, opac, feats,
                           width, height, tile, out_T, n_contrib, g_out, g_T, pair_grad):
    """Per-pair gradients. pair_grad (n_pairs, 6 + C) rows:
    d u, d v, d conic_a, d conic_b, d conic_c, d opacity, d feats[0..C)."""
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    C = feats.shape[1]
    for t in prange(tiles_x * tiles_y):
        ty = t // tiles_x
        tx = t - ty * tiles_x
        start = offsets[t]
        m = offsets[t + 1] - start
        lu = np.empty(m)
        lv = np.empty(m)
        la = np.empty(m)
        lb = np.empty(m)
        lc = np.empty(m)
        lo = np.empty(m)
        lf = np.empty((m, C))
        lg = np.zeros((m, 6 + C))
        for k in range(m):
            g = gids[start + k]
            lu[k] = means2d[g, 0]
            lv[k] = means2d[g, 1]
            la[k] = conics[g, 0]
            lb[k] = conics[g, 1]
            lc[k] = conics[g, 2]
            lo[k] = opac[g]
            for c in range(C):
                lf[k, c] = feats[g, c]
        lrx = np.empty(m)
        lry = np.empty(m)
        lpm = np.empty(m)
        _extents(la, lb, lc, lo, lrx, lry, lpm)
        rl = np.empty(m + 1, dtype=np.int64)
        sl = np.empty(m + 1, dtype=np.int64)
        go = np.empty(C)
        jend = min(width, (tx + 1) * tile)
        for i in range(ty * tile, min(height, (ty + 1) * tile)):
            py = i + 0.5
            mr = _row_list(lv, lry, py, rl)
            for j in range(tx * tile, jend):
                if (j - tx * tile) % CHUNK == 0:
                    ms = _seg_list(lu, lrx, rl, mr, j + 0.5, min(j + CHUNK, jend) - 0.5, sl)
                px = j + 0.5
                T_final = float(out_T[i, j])
                T = T_final
                gT = float(g_T[i, j])
                Sg = 0.0  # sum over Gaussians behind of w_j * (f_j . g_out)
                for c in range(C):
                    go[c] = g_out[i, j, c]
                last = n_contrib[i, j]
                for r in range(ms - 1, -1, -1):
                    k = sl[r]
                    if k >= last:
                        continue
                    dx = lu[k] - px
                    dy = lv[k] - py
                    power = -0.5 * (la[k] * dx * dx + lc[k] * dy * dy) - lb[k] * dx * dy
                    if power > 0.0 or power < lpm[k]:
                        continue  # cheap pre-test; the exact tests follow
                    if power < POWER_MIN:
                        continue
                    G = math.exp(power)
                    a_raw = lo[k] * G
                    alpha = min(ALPHA_MAX, a_raw)
                    if alpha < ALPHA_MIN:
                        continue
                    inv_om = 1.0 / (1.0 - alpha)
                    T = T * inv_om  # transmittance in front of this Gaussian
                    w = alpha * T
                    dotf = 0.0
                    for c in range(C):
                        dotf += go[c] * lf[k, c]
                        lg[k, 6 + c] += w * go[c]
                    # dL/dalpha = T f.g - (sum_{behind} w_j f_j.g + gT T_final) / (1 - alpha)
                    g_alpha = T * dotf - (Sg + gT * T_final) * inv_om
                    Sg += w * dotf
                    if a_raw > ALPHA_MAX:
                        continue  # clamped: no gradient to opacity or shape
                    lg[k, 5] += G * g_alpha
                    gp = alpha * g_alpha  # dL/dpower
                    lg[k, 0] += -gp * (la[k] * dx + lb[k] * dy)
                    lg[k, 1] += -gp * (lb[k] * dx + lc[k] * dy)
                    lg[k, 2] += -0.5 * gp * dx * dx
                    lg[k, 3] += -gp * dx * dy
                    lg[k, 4] += -0.5 * gp * dy * dy
        for k in range(m):
            for c in range(6 + C):
                pair_grad[start + k, c] = lg[k, c]
