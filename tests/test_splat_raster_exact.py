"""The SIMD compositing kernels against a plain pixel-by-pixel loop of the same
rules, on hard cases: the closed-form row spans and the 8-lane segments must
only pre-filter, never change a pixel (forward: same bits), and the exp they
use must stay within 1.5 ulp of the exact exponential."""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import numpy as np
import pytest

from gs2e.splat import raster as R


def _pixel_loop_forward(means2d, conics, opac, feats, bg, W, H, offsets, gids, tile,
                        ftype=float, exp_neg=R._exp_neg):
    """Pixel-major compositing, every Gaussian of the tile list tested at every
    pixel, each operation in ``ftype`` in the kernels' order: Python floats
    (IEEE double, like the float64 kernel without fast-math) or numpy float32
    scalars with ``exp_neg=R._exp_neg_f32`` (the float32 kernel; its
    multiply-adds fused, here by :func:`R._mul_add`'s exact rational reference). The opacity
    and determinant cuts and lpm are computed in double, as the kernels' set-up."""
    C = feats.shape[1]
    tiles_x = (W + tile - 1) // tile
    dt = np.float64 if ftype is float else ftype
    out = np.zeros((H, W, C), dt)
    out_T = np.zeros((H, W), dt)
    n_contrib = np.zeros((H, W), np.int64)
    one, half, zero = ftype(1.0), ftype(0.5), ftype(0.0)
    a_max, a_min, t_min = ftype(R.ALPHA_MAX), ftype(R.ALPHA_MIN), ftype(R.T_MIN)
    for i in range(H):
        for j in range(W):
            t = (i // tile) * tiles_x + j // tile
            lst = gids[offsets[t]:offsets[t + 1]]
            T, acc, last = one, [zero] * C, len(lst)
            for k, g in enumerate(lst):
                o = float(opac[g])
                a, b, c = (float(x) for x in conics[g])
                if o < R.ALPHA_MIN or not a * c - b * b > 0.0:
                    continue
                lpm = ftype(max(R.POWER_MIN, math.log(R.ALPHA_MIN / o)) - 1e-6)
                a, b, c, o = ftype(a), ftype(b), ftype(c), ftype(o)
                dx = ftype(means2d[g, 0]) - (ftype(j) + half)
                dy = ftype(means2d[g, 1]) - (ftype(i) + half)
                power = R._mul_add(-(b * dx), dy, -half * R._mul_add(a * dx, dx, c * dy * dy))
                if power > 0.0 or power < lpm or power < R.POWER_MIN:
                    continue
                alpha = min(a_max, o * exp_neg(power))
                if alpha < a_min:
                    continue
                t_next = T * (one - alpha)
                if t_next < t_min:
                    last = k
                    break
                w = alpha * T
                for ch in range(C):
                    acc[ch] = R._mul_add(ftype(feats[g, ch]), w, acc[ch])
                T = t_next
            for ch in range(C):
                out[i, j, ch] = R._mul_add(T, ftype(bg[ch]), acc[ch])
            out_T[i, j] = T
            n_contrib[i, j] = last
    return out, out_T, n_contrib


def _hard_scene(seed, n, W, H, dtype):
    """Round, needle-thin (near-singular conic) and huge Gaussians, opaque
    stacks, centres on pixel centres and ellipses tangent to them."""
    rng = np.random.default_rng(seed)
    means2d = np.column_stack([rng.uniform(-8, W + 8, n), rng.uniform(-8, H + 8, n)])
    means2d[: n // 8] = np.round(means2d[: n // 8]) + 0.5  # on a pixel centre
    sig = np.exp(rng.uniform(np.log(0.55), np.log(12.0), (n, 2)))
    sig[n // 4: n // 2, 1] = 0.55  # needles: aspect up to ~20 ...
    sig[n // 4: n // 2, 0] = rng.uniform(8.0, 12.0, n // 2 - n // 4)
    th = rng.uniform(0, np.pi, n)
    cs, sn = np.cos(th), np.sin(th)
    cov = np.empty((n, 2, 2))
    cov[:, 0, 0] = cs ** 2 * sig[:, 0] ** 2 + sn ** 2 * sig[:, 1] ** 2
    cov[:, 1, 1] = sn ** 2 * sig[:, 0] ** 2 + cs ** 2 * sig[:, 1] ** 2
    cov[:, 0, 1] = cov[:, 1, 0] = cs * sn * (sig[:, 0] ** 2 - sig[:, 1] ** 2)
    inv = np.linalg.inv(cov)
    conics = np.column_stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]])
    # ... and nearly degenerate ones (det / (a c) ~ 1e-7)
    k = slice(n // 2, n // 2 + n // 16)
    conics[k, 1] = np.sqrt(conics[k, 0] * conics[k, 2]) * (1 - 1e-7)
    opac = rng.uniform(0.0, 1.0, n)
    opac[: n // 4] = 0.995  # opaque: alphas clamp ...
    means2d[:6] = [W / 2, H / 2] + rng.uniform(-1, 1, (6, 2))  # ... and a stack stops pixels
    conics[:6] = [0.1, 0.0, 0.1]
    opac[n - n // 10:] = rng.uniform(0.0, 2.0 / 255.0, n // 10)  # around the 1/255 cut
    # tangent: the ellipse's lowest point exactly on a pixel row's centre line
    t = slice(n // 2 + n // 16, n // 2 + n // 8)
    var_y = conics[t, 0] / (conics[t, 0] * conics[t, 2] - conics[t, 1] ** 2)
    means2d[t, 1] = np.floor(means2d[t, 1]) + 0.5 - 3.0 * np.sqrt(var_y)
    return (means2d.astype(dtype), conics.astype(dtype), opac.astype(dtype),
            rng.random((n, 4)).astype(dtype), rng.random(4).astype(dtype), rng.random(n))


@pytest.mark.parametrize("tile,W,H,C,dtype", [(16, 61, 37, 3, np.float32), (16, 48, 32, 4, np.float64),
                                              (12, 50, 29, 1, np.float64), (8, 33, 20, 2, np.float32),
                                              (24, 70, 30, 4, np.float32)])
def test_forward_same_bits_as_pixel_loop(tile, W, H, C, dtype):
    n = W * H // 25
    m2, cn, op, feats, bg, depth = _hard_scene(tile + C, n, W, H, dtype)
    feats, bg = np.ascontiguousarray(feats[:, :C]), np.ascontiguousarray(bg[:C])
    radii = np.full(n, 40.0)
    offsets, gids = R.bin_gaussians(m2, depth, radii, W, H, tile, op)
    out, out_T, nc = R.rasterize_forward(m2, cn, op, feats, bg, W, H, offsets, gids, tile)
    ref, ref_T, ref_nc = _pixel_loop_forward(m2, cn, op, feats, bg, W, H, offsets, gids, tile)
    np.testing.assert_array_equal(out, ref.astype(dtype))
    np.testing.assert_array_equal(out_T, ref_T.astype(dtype))
    np.testing.assert_array_equal(nc, ref_nc)
    tiles_x = (W + tile - 1) // tile
    ti = (np.arange(H)[:, None] // tile) * tiles_x + np.arange(W)[None, :] // tile
    assert (nc < np.diff(offsets)[ti]).sum() >= 3  # some pixels stopped early
    assert float(out_T.max()) > 0.3  # ... and some stayed open


def test_backward_matches_pixel_loop_order_free():
    """The backward sums each pair's gradient per lane, then over lanes: a
    different order from a pixel loop, so equal to rounding, not bits. The
    reference is the forward's own chain rule through finite differences of
    the pixel loop (central, in float64) on a small case."""
    W, H, tile = 20, 13, 16
    m2, cn, op, feats, bg, depth = _hard_scene(3, 24, W, H, np.float64)
    op = np.minimum(op, 0.9)  # finite differences need no clamp kinks
    feats, bg = feats[:, :3].copy(), bg[:3].copy()
    offsets, gids = R.bin_gaussians(m2, depth, np.full(24, 40.0), W, H, tile, op)
    out, out_T, nc = R.rasterize_forward(m2, cn, op, feats, bg, W, H, offsets, gids, tile)
    rng = np.random.default_rng(0)
    g_out, g_T = rng.standard_normal(out.shape), rng.standard_normal(out_T.shape)
    grads = R.rasterize_backward(m2, cn, op, feats, W, H, offsets, gids, out_T, nc,
                                 g_out, g_T, tile)

    def loss(m2_, cn_, op_, f_):
        o, T, _ = _pixel_loop_forward(m2_, cn_, op_, f_, np.zeros(3), W, H, offsets, gids, tile)
        return float((o * g_out).sum() + (T * g_T).sum())

    eps = 1e-6
    checked = 0
    for g in range(0, 24, 5):
        # (argument, index, gradient column): u, v, conic a, b, c, opacity, first feature
        for which, idx, col in [(0, (g, 0), 0), (0, (g, 1), 1), (1, (g, 0), 2), (1, (g, 1), 3),
                                (1, (g, 2), 4), (2, (g,), 5), (3, (g, 0), 6)]:
            args = [m2.copy(), cn.copy(), op.copy(), feats.copy()]
            args[which][idx] += eps
            lp = loss(*args)
            args[which][idx] -= 2 * eps
            num = (lp - loss(*args)) / (2 * eps)
            assert abs(grads[g, col] - num) <= 1e-5 * (1 + abs(num)), (g, col, grads[g], num)
            checked += abs(num) > 1e-3
    assert checked >= 10  # not all flat


def test_exp_within_one_and_a_half_ulp():
    xs = np.concatenate([-np.linspace(0, 4.5, 4001), -np.arange(289) / 64 - 1 / 128,
                         -np.arange(289) / 64 + 1 / 128, [-4.5 - 1e-6, -1e-300, -0.0]])
    xs = xs[(xs <= 0) & (xs >= -4.5 - 1e-6)]
    with localcontext() as ctx:
        ctx.prec = 40
        worst = 0.0
        for x in xs:
            exact = Decimal(float(x)).exp()
            err = abs(Decimal(R._exp_neg(float(x))) - exact) / Decimal(math.ulp(float(exact)))
            worst = max(worst, float(err))
    assert worst <= 1.5, worst
    assert R._exp_neg(0.0) == 1.0


def test_more_than_four_channels_refused():
    z = np.zeros((1, 5))
    with pytest.raises(ValueError, match="1 to 4 feature channels"):
        R.rasterize_forward(np.zeros((1, 2)), np.ones((1, 3)), np.ones(1), z, np.zeros(5), 16, 16,
                            np.zeros(2, np.int64), np.zeros(0, np.int32))


def _col_span(u, dy, a, b, det, m2, inv_a, x0, tw):
    """The column rule the kernels used before the squared-distance test:
    the row's chord a dx^2 + 2 b dx dy + c dy^2 <= m2 solved for dx, widened
    by 1e-6 relative and 1e-3 px, rounded to tile-local columns (inclusive;
    empty if lo > hi)."""
    D = a * m2 - det * dy * dy + 1e-6 * a * m2
    if D < 0.0:
        return 0, -1
    hw = math.sqrt(D) * inv_a * (1.0 + 1e-6) + 1e-3
    cx = u + b * dy * inv_a
    return (max(0, int(math.ceil(cx - hw - 0.5)) - x0),
            min(tw - 1, int(math.floor(cx + hw - 0.5)) - x0))


@pytest.mark.parametrize("lanes", [16, 8])
def test_reach_test_keeps_every_segment_the_column_rule_keeps(lanes):
    """The kernels decide which segments of a tile row a Gaussian reaches by
    squared distances (:func:`R._row_reached` on each segment's pixel
    centres: one segment per row at 16 lanes, two at 8). Every segment
    holding a column that the column rule keeps must be kept (the segment
    then tests each pixel exactly); segments kept in excess must stay rare.
    Hard cases: needles, near-singular conics, huge ellipses, and chords whose
    end lies within 1e-9 .. 2e-3 px of the first or last pixel centre of the
    tile row or of a segment. The kernels' path (all rows at once,
    :func:`R._rows_reached`, then :func:`R._row_segments`) gives the same
    segments as the row-at-a-time :func:`R._segments_of`."""
    rng = np.random.default_rng(7)
    m2_, cn_, op_ = _hard_scene(11, 4000, 64, 64, np.float64)[:3]
    x0, tw = 16, 16
    nseg = tw // lanes
    kept_col = kept_seg = missed = 0
    cases = []
    for g in range(len(op_)):
        o, (a, b, c) = float(op_[g]), (float(x) for x in cn_[g])
        lpm, m2, det = R._footprint(o, a, b, c)
        if lpm > 0.0:
            continue
        cases.append((float(m2_[g, 0]) - 24.0 + 40.0, a, b, det, m2))
    # chords ending next to a pixel centre at a segment's end (both ends, both sides)
    ends = sorted({x0 + 0.5 + h * lanes + e for h in range(nseg) for e in (0, lanes - 1)})
    for _ in range(4000):
        o = rng.uniform(0.02, 1.0)
        sx, sy, th = np.exp(rng.uniform(np.log(0.3), np.log(40.0), 2)).tolist() + [rng.uniform(0, np.pi)]
        cs, sn = math.cos(th), math.sin(th)
        cxx = cs * cs * sx * sx + sn * sn * sy * sy
        cyy = sn * sn * sx * sx + cs * cs * sy * sy
        cxy = cs * sn * (sx * sx - sy * sy)
        dd = cxx * cyy - cxy * cxy
        a, b, c = cyy / dd, -cxy / dd, cxx / dd
        lpm, m2, det = R._footprint(o, a, b, c)
        if lpm > 0.0:
            continue
        dy = rng.uniform(-1.0, 1.0) * math.sqrt(m2 * a / det)
        hw = math.sqrt(max(a * m2 - det * dy * dy, 0.0)) / a
        end = ends[rng.integers(0, len(ends))]
        side = rng.choice([-1.0, 1.0])
        eps = rng.choice([0.0, 1e-9, -1e-9, 1e-6, -1e-6, 1e-3, -1e-3, 2e-3, -2e-3])
        cx = end - side * hw + eps  # cx + side * hw lands next to a centre
        cases.append((cx - b * dy / a, a, b, det, m2, dy))
    for case in cases:
        u, a, b, det, m2 = case[:5]
        rows = [case[5]] if len(case) > 5 else [(u - 40.0) - (i + 0.5) for i in range(-2, 18)]
        for dy in rows:
            j_lo, j_hi = _col_span(u, dy, a, b, det, m2, 1.0 / a, x0, tw)
            h_lo, h_hi = R._segments_of(u, dy, a, b, det, m2, 1.0 / a, x0, tw, lanes, nseg)
            col = set(range(j_lo // lanes, j_hi // lanes + 1)) if j_lo <= j_hi else set()
            seg = set(range(h_lo, h_hi + 1))
            natural = len(case) == 5  # the scene's rows, not built at the margins
            kept_col += natural * len(col)
            kept_seg += natural * len(seg)
            missed += len(col - seg)
    assert kept_col > 5_000, kept_col
    assert missed == 0, missed
    assert kept_seg - kept_col <= 0.01 * kept_col, (kept_seg, kept_col)
    # the kernels' path: every row of the tile at once, then per row
    reached = np.zeros(16 * nseg, np.bool_)
    for u, a, b, det, m2 in [cs_[:5] for cs_ in cases[:500]]:
        v, y0 = 40.0, 24
        i_lo, i_hi = 0, 15
        reached[:] = False
        R._rows_reached(reached, i_lo, i_hi, u, v, a, b, det, m2, 1.0 / a, x0, y0, tw, lanes,
                        nseg, lanes < 16)
        for ii in range(16):
            dy = v - (y0 + ii + 0.5)
            got = R._row_segments(reached, ii, u, v, a, b, det, m2, 1.0 / a, x0, y0, tw, lanes,
                                  nseg, lanes < 16)
            want = R._segments_of(u, dy, a, b, det, m2, 1.0 / a, x0, tw, lanes, nseg)
            assert (got[0] > got[1] and want[0] > want[1]) or got == want, (got, want)


def test_float32_inputs_reach_the_pixels_float64_inputs_reach():
    """The per-Gaussian set-up is float64 whatever the inputs' type. A needle
    (the conic of one of a trained llff_fern model's Gaussians: det = a c - b^2
    cancels to 1e-3 of a c) placed so that pixel (row 37, column 40), the
    first of a segment, lies 1e-3 px inside the end of its row's chord near
    the needle's tip, the rest of the chord in the segment before: the pixel
    passes the per-pixel test (checked here in float64), and with det rounded
    to float32 (numba's float() keeps float32) the half-chord shrank by
    8e-3 px, beyond the reach test's margin, so the pixel was dropped.
    (float64 compositing: in float32 the pixel's own power is rounded by
    more than that margin.)"""
    m2d = np.array([[-63.73100280761719, 17.68130111694336]])
    cn = np.array([[0.10061904788017273, -0.5289574265480042, 2.8036584854125977]])
    op = np.array([0.996060848236084])
    feats = np.array([[0.4664444, 0.4307131, 0.3698446]])
    a, b, c = (float(np.float32(x)) for x in cn[0])
    dx, dy = m2d[0, 0] - 40.5, m2d[0, 1] - 37.5
    lpm = R._footprint(float(np.float32(op[0])), a, b, c)[0]
    assert -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy >= lpm + 1e-6  # the pixel is reached
    W, H = 64, 48
    offsets, gids = R.bin_gaussians(m2d, np.ones(1), np.array([120], np.int32), W, H, 16, op)
    res = {}
    for dt in (np.float64, np.float32):
        res[dt] = R.rasterize_forward(m2d.astype(dt), cn.astype(dt), op.astype(dt), feats.astype(dt),
                                      np.zeros(3, dt), W, H, offsets, gids,
                                      compute_dtype=np.float64)
        assert res[dt][1][37, 40] < 0.995, dt  # alpha ~ 0.011
    assert np.array_equal(res[np.float32][1] < 1.0, res[np.float64][1] < 1.0)
