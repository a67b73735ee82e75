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

Per tile, each pixel row and each CHUNK-pixel segment of it first compacts
(branch-free) the candidates whose ellipse (3 sigma, or smaller where a low
opacity keeps alpha under 1/255) reaches it; the exact per-pixel tests then
decide, so these pre-filters never change the result (tested).

Channels: any number C of per-Gaussian features are composited together
(RGB plus camera depth, so expected depth comes for free).

Determinism: each tile is handled by one thread, which writes the gradients
of its (tile, Gaussian) pairs into its own rows of a pair buffer; the buffer is
then reduced per Gaussian serially in pair order. No atomics, same bits every
run, whatever the thread count.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

ALPHA_MAX = 0.99
ALPHA_MIN = 1.0 / 255.0
T_MIN = 1.0e-4
POWER_MIN = -4.5  # 3 sigma: -0.5 * 3^2


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


@njit(cache=True, fastmath=False)
def bin_kernel(order, means2d, radii, width, height, tile):
    """Per-tile Gaussian lists in the given (depth) order.

    Returns tile_offsets (n_tiles+1,) int64 and tile_gids (n_pairs,) int32.
    """
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    n_tiles = tiles_x * tiles_y
    counts = np.zeros(n_tiles + 1, dtype=np.int64)
    for gi in range(order.shape[0]):
        g = order[gi]
        r = float(radii[g])
        if r <= 0:
            continue
        x0, x1, y0, y1 = _tile_rect(float(means2d[g, 0]), float(means2d[g, 1]), r,
                                    width, height, tile, tiles_x, tiles_y)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                counts[ty * tiles_x + tx + 1] += 1
    for t in range(n_tiles):
        counts[t + 1] += counts[t]
    fill = counts[:-1].copy()
    gids = np.empty(counts[n_tiles], dtype=np.int32)
    for gi in range(order.shape[0]):
        g = order[gi]
        r = float(radii[g])
        if r <= 0:
            continue
        x0, x1, y0, y1 = _tile_rect(float(means2d[g, 0]), float(means2d[g, 1]), r,
                                    width, height, tile, tiles_x, tiles_y)
        for ty in range(y0, y1 + 1):
            for tx in range(x0, x1 + 1):
                t = ty * tiles_x + tx
                gids[fill[t]] = g
                fill[t] += 1
    return counts, gids


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
    vis = np.flatnonzero(r > 0)
    order = vis[np.argsort(depths[vis], kind="stable")].astype(np.int64)
    return bin_kernel(order, means2d, r, int(width), int(height), int(tile))


def rasterize_forward(means2d, conics, opac, feats, bg, width, height, offsets, gids, tile=16):
    """Composite features front to back.

    Parameters
    ----------
    means2d (N,2) px; conics (N,3); opac (N,) in [0,1]; feats (N,C); bg (C,);
    all of one float dtype (float32 or float64), which the outputs take.

    Returns
    -------
    out (H,W,C) composited features incl. background, out_T (H,W) final
    transmittance, n_contrib (H,W) int32.
    """
    dt = feats.dtype
    C = feats.shape[1]
    out = np.empty((height, width, C), dtype=dt)
    out_T = np.empty((height, width), dtype=dt)
    n_contrib = np.empty((height, width), dtype=np.int32)
    n_tiles = ((int(width) + tile - 1) // tile) * ((int(height) + tile - 1) // tile)
    raster_forward_kernel(np.arange(n_tiles, dtype=np.int64), offsets, gids, means2d, conics,
                          opac, feats, bg, int(width), int(height), int(tile), out, out_T, n_contrib)
    return out, out_T, n_contrib


def rasterize_backward(means2d, conics, opac, feats, width, height, offsets, gids,
                       out_T, n_contrib, g_out, g_T, tile=16):
    """Backward of :func:`rasterize_forward`.

    g_out (H,W,C) gradient of ``out``; g_T (H,W) gradient of the final
    transmittance (the background term is added by the caller).

    Returns float64 (N, 6 + C): d u, d v, d conic a, b, c, d opacity, d feats.
    """
    n = means2d.shape[0]
    C = feats.shape[1]
    pair_grad = np.empty((gids.shape[0], 6 + C), dtype=np.float64)
    raster_backward_kernel(offsets, gids, means2d, conics, opac, feats,
                           int(width), int(height), int(tile), out_T, n_contrib,
                           g_out, g_T, pair_grad)
    grads = np.zeros((n, 6 + C), dtype=np.float64)
    reduce_pairs_kernel(gids, pair_grad, grads)
    return grads
