"""Optical flow from events alone: contrast maximisation (Gallego, Rebecq and
Scaramuzza, "A Unifying Contrast Maximization Framework for Event Cameras",
CVPR 2018), and its scores against ground truth.

Within a window of duration T, events of a patch whose image moves by d
pixels over the window are warped to the window's middle, x' = x - d (t/T -
1/2); the right d stacks each edge's events on one place, so the image of
warped events (IWE: bilinear votes, Gaussian-smoothed) is sharpest: its
variance is largest. :func:`contrast_maximisation` finds a d per patch
(all patches at once: each patch votes into its own canvas of a mosaic, so
one smoothing serves every patch and candidate), coarse to fine in time, and
median-filters the patches' flows over their neighbours and interpolates
them to every pixel; isolated events are dropped first, patches with too few
events take the others' median. No parameter comes from the ground truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class CMSettings:
    """patch_px : side of the patches that get a flow of their own (px).
    min_events : a patch with fewer events takes the median flow of the others.
    min_support : an event counts only if the window holds at least this many
        events in its 3 x 3 pixel neighbourhood, itself included (a
        background-activity filter: isolated noise events sharpen nothing).
    max_events : events used per sub-window (an evenly strided subset beyond).
    max_flow_fraction : flows up to this fraction of the image's longer side
        over the window are searched for.
    start_px : the first sub-window is short enough that the largest flow
        moves at most this far in it (px); its search is exhaustive over that.
    grid : candidates per axis of that exhaustive search (odd).
    min_step_px : the searches stop below this step (px).
    max_scale : the finest scale the warped events are drawn at (smoothed by 1
        px there): 0.5 = 2 px. On the demo's DVS-Voltmeter events, 1.0 was
        more accurate at medium and strong but worse than zero flow at mild,
        at 2.4x the CPU (15 windows, 2026-11-29).

    The patches' flows are median-filtered over their 3 x 3 neighbours: a
    patch of little texture (or noise) finds a wrong sharpest warp on its own.
    On 18 DAVIS346 windows of four scenes (demo, mouse_colmap, temple_ring,
    llff_fern at mild to strong; DVS-Voltmeter with the davis346 noise), 32 px
    patches without the filter lost to zero flow on two of six cases
    (mouse_colmap mild 14.4 against 9.6 px); 64 px patches with the filter and
    the support rule beat it on all six, at 0.36x the CPU (2026-11-29).
    """

    patch_px: int = 64
    min_events: int = 30
    min_support: int = 3
    max_events: int = 10000
    max_flow_fraction: float = 0.5
    start_px: float = 12.0
    grid: int = 7
    min_step_px: float = 0.2
    max_scale: float = 0.5


def _iwe(xw: np.ndarray, yw: np.ndarray, shape: tuple[int, int], sigma: float) -> np.ndarray:
    """Image of warped events (``shape`` = (rows, cols) px): bilinear votes of
    the events at pixel coordinates (xw, yw) (votes off the image are
    dropped), smoothed by a Gaussian of ``sigma`` px."""
    import cv2

    Hm, Wm = shape
    x0 = np.floor(xw).astype(np.int64)
    y0 = np.floor(yw).astype(np.int64)
    ax, ay = xw - x0, yw - y0
    xi = np.concatenate([x0, x0 + 1, x0, x0 + 1])
    yi = np.concatenate([y0, y0, y0 + 1, y0 + 1])
    w = np.concatenate([(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay])
    ok = (xi >= 0) & (xi < Wm) & (yi >= 0) & (yi < Hm)
    img = np.bincount(yi[ok] * Wm + xi[ok], weights=w[ok], minlength=Hm * Wm).astype(np.float32)
    return cv2.GaussianBlur(img.reshape(Hm, Wm), (0, 0), sigma, borderType=cv2.BORDER_CONSTANT)


class _Patches:
    """The events of one (sub-)window split by patch, and the sharpness of
    their warped images for a displacement per patch: each patch votes into
    its own canvas (the patch plus the warps' reach) of a mosaic, so one
    smoothing serves all patches."""

    def __init__(self, x, y, s, width, height, P, max_scale):
        self.x, self.y, self.s, self.P, self.max_scale = x, y, s, P, max_scale
        self.cols, self.rows = max(1, -(-width // P)), max(1, -(-height // P))
        self.cell = (np.minimum(y.astype(np.int64) // P, self.rows - 1) * self.cols
                     + np.minimum(x.astype(np.int64) // P, self.cols - 1))
        self.n = self.rows * self.cols
        ci = np.arange(self.n)
        self.corner = np.stack([(ci % self.cols) * P, (ci // self.cols) * P], 1).astype(np.float64)

    def sharpness(self, cands: list[np.ndarray], f: float) -> np.ndarray:
        """Variance (len(cands), n) of each patch's smoothed image of events
        warped by each candidate displacement (n, 2) (image drawn at scale f,
        smoothed by 1 px there)."""
        c = self.cell
        reach = max(float(np.abs(d).max()) for d in cands) / 2 + 3.0 / f
        side = int(math.ceil((self.P + 2 * reach) * f)) + 1
        ox = (self.corner[c, 0] - reach) * f - (c % self.cols) * side
        oy = (self.corner[c, 1] - reach) * f - (c // self.cols) * side
        out = np.empty((len(cands), self.n))
        for k, d in enumerate(cands):
            img = _iwe((self.x - d[c, 0] * self.s) * f - ox, (self.y - d[c, 1] * self.s) * f - oy,
                       (self.rows * side, self.cols * side), 1.0)
            cells = img.reshape(self.rows, side, self.cols, side)
            m1 = cells.sum(axis=(1, 3), dtype=np.float64)
            m2 = np.einsum("aibj,aibj->ab", cells, cells, dtype=np.float64)
            out[k] = (m2 / (side * side) - (m1 / (side * side)) ** 2).reshape(-1)
        return out

    def grid_search(self, d: np.ndarray, radius: float, grid: int, min_step: float) -> np.ndarray:
        """Coarse-to-fine: every patch tries d plus a grid x grid lattice of
        half-width r, keeps its best, r shrinks to the lattice step."""
        r = float(radius)
        while True:
            step = 2 * r / (grid - 1)
            offs = np.linspace(-r, r, grid)
            cands = [d + (ox, oy) for oy in offs for ox in offs]
            v = self.sharpness(cands, min(self.max_scale, 2.0 / step))
            d = np.stack(cands)[np.argmax(v, axis=0), np.arange(self.n)]
            if step <= min_step:
                return d
            r = step

    def pattern_search(self, d: np.ndarray, step: float, min_step: float) -> np.ndarray:
        """Each patch moves to the best of its four neighbours at +-step while
        one is sharper, then halves the step, down to min_step."""
        moves = np.array([[0, 0], [1, 0], [-1, 0], [0, 1], [0, -1]], np.float64)
        while step >= min_step:
            for _ in range(4):
                cands = [d + m * step for m in moves]
                best = np.argmax(self.sharpness(cands, min(self.max_scale, 2.0 / step)), axis=0)
                d = np.stack(cands)[best, np.arange(self.n)]
                if not best.any():
                    break
            step /= 2
        return d


def contrast_maximisation(x: np.ndarray, y: np.ndarray, t_us: np.ndarray, t0_us: int, t1_us: int,
                          width: int, height: int, st: CMSettings = CMSettings()) -> np.ndarray:
    """Dense flow (H, W, 2) px over the window [t0_us, t1_us) from its events
    (pixel x, y, times t_us) by contrast maximisation (module docstring).

    Coarse to fine in time: the first sub-window, centred in the window, is
    so short that the largest flow searched for (``max_flow_fraction`` of the
    image) moves at most ``start_px`` in it, and every patch's displacement
    there is found by an exhaustive search; each next sub-window is twice as
    long, its displacement predicted as twice the last and refined by a
    pattern search, up to the whole window. Displacements far beyond a
    patch defeat a search over the whole window at once: their smoothed
    images differ too little (checked on synthetic dots). The patches' flows
    are interpolated between patch centres; zero flow without events.
    """
    import cv2

    if len(x) == 0 or t1_us <= t0_us:
        return np.zeros((height, width, 2))
    x, y, t_us = np.asarray(x), np.asarray(y), np.asarray(t_us)
    if st.min_support > 1:  # drop isolated events (background activity)
        pix = y.astype(np.int64) * width + x.astype(np.int64)
        cnt = np.bincount(pix, minlength=height * width).astype(np.float32).reshape(height, width)
        box = cv2.boxFilter(cnt, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        keep = box.reshape(-1)[pix] >= st.min_support
        x, y, t_us = x[keep], y[keep], t_us[keep]
        if len(x) == 0:
            return np.zeros((height, width, 2))
    x = x.astype(np.float64) + 0.5
    y = y.astype(np.float64) + 0.5
    s = (t_us.astype(np.float64) - t0_us) / float(t1_us - t0_us) - 0.5
    R = st.max_flow_fraction * max(width, height)
    levels = max(0, int(math.ceil(math.log2(R / st.start_px))))
    d = None
    for k in range(levels + 1):
        phi = 2.0 ** (k - levels)  # the sub-window's share of the window
        sel = np.flatnonzero(np.abs(s) <= phi / 2)
        if len(sel) > st.max_events:  # an evenly strided subset, in time order
            sel = sel[np.linspace(0, len(sel) - 1, st.max_events).astype(np.int64)]
        pts = _Patches(x[sel], y[sel], s[sel] / phi, width, height, st.patch_px, st.max_scale)
        if d is None:
            d_sub = pts.grid_search(np.zeros((pts.n, 2)), R * phi, st.grid, st.min_step_px)
        else:
            d_sub = pts.pattern_search(d * phi, 2.0, st.min_step_px)
        d = d_sub / phi
    few = np.bincount(pts.cell, minlength=pts.n) < st.min_events
    if few.all():
        return np.zeros((height, width, 2))
    d[few] = np.median(d[~few], axis=0)
    from scipy.ndimage import median_filter

    grid = d.reshape(pts.rows, pts.cols, 2)
    grid = np.stack([median_filter(grid[..., c], size=3, mode="nearest") for c in range(2)], -1)
    grid = grid.astype(np.float32)
    # patch centres to pixels (bilinear; constant beyond the outer centres)
    P = st.patch_px
    dense = cv2.resize(grid, (pts.cols * P, pts.rows * P), interpolation=cv2.INTER_LINEAR)
    return dense[:height, :width].astype(np.float64)


def flow_errors(flow: np.ndarray, gt: np.ndarray, valid: np.ndarray) -> dict[str, float]:
    """Average endpoint error (px) and the share of pixels over 3 px (DSEC's
    "3PE"; KITTI's outlier rule without its 5 % relative part) over the valid
    pixels; NaN when none is valid."""
    v = np.asarray(valid, bool) & np.all(np.isfinite(gt), axis=-1)
    if not v.any():
        return {"aee_px": math.nan, "out_3px": math.nan, "n_valid": 0}
    e = np.linalg.norm(flow[v] - gt[v], axis=-1)
    return {"aee_px": float(e.mean()), "out_3px": float((e > 3.0).mean()), "n_valid": int(v.sum())}


def flow_colour(flow: np.ndarray, max_px: float | None = None) -> np.ndarray:
    """(H, W, 3) float RGB in [0, 1] of a flow field: hue = direction, value =
    magnitude relative to ``max_px`` (default: the 99th percentile of the
    finite magnitudes); NaN flow is black."""
    import cv2

    f = np.nan_to_num(np.asarray(flow, np.float64))
    mag = np.hypot(f[..., 0], f[..., 1])
    if max_px is None:
        fin = mag[np.all(np.isfinite(flow), axis=-1)]
        max_px = float(np.percentile(fin, 99)) if fin.size else 1.0
    ang = (np.degrees(np.arctan2(f[..., 1], f[..., 0])) % 360) / 2
    hsv = np.stack([ang, np.full_like(ang, 255), np.clip(mag / max(max_px, 1e-9), 0, 1) * 255], -1)
    rgb = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB) / 255.0
    rgb[~np.all(np.isfinite(flow), axis=-1)] = 0
    return rgb
