"""Forward-only rendering of a trained model, whole images or a set of tiles.

The event stage samples a model's images thousands of times per simulated
second, mostly a few tiles at a time (:mod:`gs2e.events.sampling`). This path
keeps what such renders need and nothing else: no autograd, no depth, no
state for a backward pass; world covariances (and colours, for SH degree 0)
computed once per model; projection of only the Gaussians that can reach the
tiles asked for.

Exactness: for the tiles it renders, :meth:`ForwardRenderer.render_tiles`
gives the same pixel values, bit for bit, as :meth:`ForwardRenderer.render`
(and as :func:`gs2e.splat.rasterize.rasterize` at the same dtype): the same
projection and compositing kernels run on the same per-tile Gaussian lists
(same members, same depth order with ties by index). Only which Gaussians get
projected differs, and that is decided from :class:`TileCandidates`, a
superset of every tile's list over a span of poses.

Units: pixels with centres at integer + 0.5; ``c2w`` camera-to-world 4x4,
OpenCV axes; images (H, W, 3) sRGB-encoded in [0, 1], as 3DGS reproduces the
training photos.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import njit, prange
from scipy.special import expit

from gs2e.splat import project as _proj
from gs2e.splat import raster as _raster
from gs2e.splat import sh as _sh
from gs2e.splat.rasterize import TILE, SplatCamera


@dataclass
class TileCandidates:
    """Per tile, the Gaussians that may reach it at any pose of a span.

    ``offsets`` (n_tiles + 1,) int64 and ``gids`` (n,) int64: the candidates of
    tile t are gids[offsets[t]:offsets[t + 1]], in depth order at the span's
    middle pose (ties by index), so that each render's depth sort starts
    nearly sorted. ``speed_px`` (n_tiles,)
    float64: the largest displacement (px) of a candidate's centre between
    consecutive poses of the span, 0 for a tile without candidates;
    ``max_step_px`` the 99th percentile of that displacement over the Gaussians
    seen at consecutive poses (a robust size of the span's motion: a few
    Gaussians next to the near plane move by hundreds of pixels).
    """

    offsets: np.ndarray
    gids: np.ndarray
    speed_px: np.ndarray
    max_step_px: float = 0.0


@dataclass
class CentreProjection:
    """Where a pose puts every Gaussian's centre, for measuring image motion.

    ``uv`` (n, 2) float64 projected centres (px); ``scale_px`` (n,) the
    Gaussian's smallest projected standard deviation, at least 1 px (the
    finest image structure it can draw: moving it by d px changes its pixels
    by about d / scale_px of its contrast); ``front`` (n,) projected (in
    front of the near plane, within an image size of the view: ``uv`` valid);
    ``seen`` (n,) opaque enough to be drawn, centre in the view (10 % margin).
    """

    uv: np.ndarray
    scale_px: np.ndarray
    front: np.ndarray
    seen: np.ndarray


def image_motion_px(a: CentreProjection, b: CentreProjection) -> float:
    """Largest displacement of a drawn Gaussian's centre between two
    projections, in units of its own scale (px for Gaussians of at most 1 px):
    max |uv_b - uv_a| / max(scale_a, scale_b) over the Gaussians in front at
    both and seen at either. A Gaussian next to the near plane is large on
    screen and counts for little; one that crosses the near plane is not
    counted (its appearance is a jump no clock can bound)."""
    m = a.front & b.front & (a.seen | b.seen)
    if not m.any():
        return 0.0
    d = np.hypot(*(b.uv[m] - a.uv[m]).T)
    return float((d / np.maximum(a.scale_px[m], b.scale_px[m])).max())


@njit(cache=True)
def _cover_kernel(u, v, r, margin, everywhere, width, height, tile, counts_only, offsets, gids):
    """Bin boxes [u - r - margin, u + r + margin] (per Gaussian, over the
    union of the poses: u, v, r are (P, N); r <= 0 = not visible at that pose;
    ``everywhere`` (N,) = every tile) to tiles; first pass counts, second
    fills (ascending gid per tile)."""
    P, N = u.shape
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    fill = offsets[:-1].copy()
    for g in range(N):
        lo_u = math.inf
        hi_u = -math.inf
        lo_v = math.inf
        hi_v = -math.inf
        if everywhere[g]:
            lo_u, hi_u, lo_v, hi_v = -1e30, 1e30, -1e30, 1e30
        for p in range(P):
            if r[p, g] > 0.0:
                lo_u = min(lo_u, u[p, g] - r[p, g])
                hi_u = max(hi_u, u[p, g] + r[p, g])
                lo_v = min(lo_v, v[p, g] - r[p, g])
                hi_v = max(hi_v, v[p, g] + r[p, g])
        if lo_u > hi_u:
            continue
        m = margin[g]
        j0 = max(0, int(math.ceil(lo_u - m - 0.5)))
        j1 = min(width - 1, int(math.floor(hi_u + m - 0.5)))
        i0 = max(0, int(math.ceil(lo_v - m - 0.5)))
        i1 = min(height - 1, int(math.floor(hi_v + m - 0.5)))
        if j0 > j1 or i0 > i1:
            continue
        for ty in range(i0 // tile, i1 // tile + 1):
            for tx in range(j0 // tile, j1 // tile + 1):
                t = ty * tiles_x + tx
                if counts_only:
                    offsets[t + 1] += 1
                else:
                    gids[fill[t]] = g
                    fill[t] += 1
    return tiles_y * tiles_x


@njit(cache=True, parallel=True)
def _tile_speed(offsets, gids, disp):
    out = np.zeros(offsets.shape[0] - 1)
    for t in prange(offsets.shape[0] - 1):
        m = 0.0
        for k in range(offsets[t], offsets[t + 1]):
            m = max(m, disp[gids[k]])
        out[t] = m
    return out


@njit(cache=True)
def _union(tiles, offsets, gids, stamp, mark):
    """Distinct candidates of ``tiles`` (marked with ``mark`` in ``stamp``)."""
    n = 0
    for s in range(tiles.shape[0]):
        t = tiles[s]
        n += offsets[t + 1] - offsets[t]
    out = np.empty(n, np.int64)
    m = 0
    for s in range(tiles.shape[0]):
        t = tiles[s]
        for k in range(offsets[t], offsets[t + 1]):
            g = gids[k]
            if stamp[g] != mark:
                stamp[g] = mark
                out[m] = g
                m += 1
    return out[:m]


@njit(cache=True, parallel=True)
def _sort_by_depth(offsets, gids, depths):
    """Reorder each tile's ``gids`` by ``depths`` (stable: ties keep their order)."""
    for t in prange(offsets.shape[0] - 1):
        a, b = offsets[t], offsets[t + 1]
        seg = gids[a:b].copy()
        key = np.empty(b - a)
        for i in range(b - a):
            key[i] = depths[seg[i]]
        order = np.argsort(key, kind="mergesort")
        for i in range(b - a):
            gids[a + i] = seg[order[i]]


@njit(cache=True, parallel=True)
def _tile_lists(tiles, c_off, c_gids, rect, depths, width, tile):
    """Per tile of ``tiles``: its candidates whose tile range ``rect`` (x0, x1,
    y0, y1: :func:`_finish_subset`) holds it, sorted by depth with ties by
    index. Returns (offsets (n + 1,), gids).

    Insertion sort by (depth, index): the candidates come in depth order at a
    nearby pose (:meth:`ForwardRenderer.candidates`), so few moves are needed;
    any candidate order gives the same lists."""
    n = tiles.shape[0]
    tiles_x = (width + tile - 1) // tile
    start = np.zeros(n + 1, np.int64)
    for s in range(n):
        t = tiles[s]
        start[s + 1] = start[s] + c_off[t + 1] - c_off[t]
    buf = np.empty(start[n], np.int64)
    counts = np.zeros(n + 1, np.int64)
    for s in prange(n):
        t = tiles[s]
        ty = t // tiles_x
        tx = t - ty * tiles_x
        base = start[s]
        c = 0
        for k in range(c_off[t], c_off[t + 1]):
            g = c_gids[k]
            if rect[g, 0] <= tx <= rect[g, 1] and rect[g, 2] <= ty <= rect[g, 3]:
                d = depths[g]
                i = base + c
                while i > base:
                    h = buf[i - 1]
                    if depths[h] < d or (depths[h] == d and h < g):
                        break
                    buf[i] = h
                    i -= 1
                buf[i] = g
                c += 1
        counts[s + 1] = c
    for s in range(n):
        counts[s + 1] += counts[s]
    out = np.empty(counts[n], np.int64)
    for s in prange(n):
        base = start[s]
        for i in range(counts[s + 1] - counts[s]):
            out[counts[s] + i] = buf[base + i]
    return counts, out


@njit(cache=True)
def _differing_tiles(offsets, gids_a, gids_b) -> int:
    """How many tiles' lists differ between two orders of the same members.
    (Only swaps of Gaussians that share a pixel change a composite, but on
    trained models nearly every tile that holds a swap holds such a one:
    demo, 1-4 px of motion between the orders.)"""
    n = 0
    for t in range(offsets.shape[0] - 1):
        for k in range(offsets[t], offsets[t + 1]):
            if gids_a[k] != gids_b[k]:
                n += 1
                break
    return n


@njit(cache=True, parallel=True)
def _finish_subset(idx, means2d, conics, radii, opac, radius_factor, width, height, tile, m2_32,
                   cn_32, rect):
    """After projecting ``idx``: the range of tiles their box reaches (x0, x1,
    y0, y1 inclusive; empty if not visible: the opacity-shrunk bin radius of
    :func:`gs2e.splat.raster.bin_gaussians`) and float32 copies."""
    tiles_x = (width + tile - 1) // tile
    tiles_y = (height + tile - 1) // tile
    for k in prange(idx.shape[0]):
        g = idx[k]
        r = float(radii[g])
        x0, x1, y0, y1 = 0, -1, 0, -1
        if opac[g] >= _raster.ALPHA_MIN and r > 0.0:
            x0, x1, y0, y1 = _raster._tile_rect(means2d[g, 0], means2d[g, 1],
                                                r * radius_factor[g] * (1.0 + 1e-6) + 1e-3,
                                                width, height, tile, tiles_x, tiles_y)
        rect[g, 0] = x0
        rect[g, 1] = x1
        rect[g, 2] = y0
        rect[g, 3] = y1
        m2_32[g, 0] = means2d[g, 0]
        m2_32[g, 1] = means2d[g, 1]
        cn_32[g, 0] = conics[g, 0]
        cn_32[g, 1] = conics[g, 1]
        cn_32[g, 2] = conics[g, 2]


class ForwardRenderer:
    """Forward-only renders of one model at one camera size.

    Parameters
    ----------
    params : the model's parameter tensors (:func:`gs2e.splat.model.to_params`).
    sh_degree : active SH degree.
    fx, fy, cx, cy : intrinsics (px); width, height : image size (px).
    background : (3,) colour behind the Gaussians.
    dtype : storage dtype of the compositing inputs and the image, and the
        precision the compositing computes in (float32: what the event stage
        uses, 16 pixels per vector; float64 as the training renders at float64).
    window : the compositing window (:data:`gs2e.splat.raster.WINDOWS`; the
        model's own, :func:`gs2e.splat.model.model_window`).
    """

    def __init__(self, params, sh_degree: int, fx: float, fy: float, cx: float, cy: float,
                 width: int, height: int, background=(0.0, 0.0, 0.0), dtype=np.float32,
                 near: float = 0.01, far: float = 1.0e10, window: str = "cut"):
        self.window = _raster.check_window(window)
        def arr(k):
            x = params[k]
            return np.ascontiguousarray(x.detach().cpu().numpy() if hasattr(x, "detach") else x,
                                        dtype=np.float64)

        self.means = arr("means")
        n = self.means.shape[0]
        self.cov6 = np.empty((n, 6))
        self.quats, self.log_scales = arr("quats"), arr("log_scales")  # for the tangent pass
        _proj.cov3d_kernel(self.quats, self.log_scales, self.cov6)
        self.opac = expit(arr("opacity_logits"))
        sh = np.concatenate([arr("sh_dc"), arr("sh_rest")], axis=1) if "sh_dc" in params else arr("sh")
        self.sh_degree = int(sh_degree)
        self.sh = np.ascontiguousarray(sh[:, :(self.sh_degree + 1) ** 2])
        self.cam = SplatCamera(np.eye(4), float(fx), float(fy), float(cx), float(cy), int(width),
                               int(height), float(near), float(far))
        self.width, self.height = int(width), int(height)
        self.tiles_x = (self.width + TILE - 1) // TILE
        self.tiles_y = (self.height + TILE - 1) // TILE
        self.n_tiles = self.tiles_x * self.tiles_y
        self.dtype = np.dtype(dtype)
        self.bg = np.asarray(background, dtype=self.dtype)
        if self.bg.shape != (3,):
            raise ValueError(f"background must have 3 values, got {background}")
        # bin radius factor of bin_gaussians (same numpy arithmetic: same bits)
        with np.errstate(divide="ignore"):
            m2 = np.clip(2.0 * np.log(np.maximum(self.opac, 1e-300) / _raster.ALPHA_MIN), 0.0, 9.0)
        self.radius_factor = np.sqrt(m2 / 9.0)
        self.opac_dt = self.opac.astype(self.dtype)
        self._binned = self.opac >= _raster.ALPHA_MIN  # opaque enough to enter a tile list
        # per-Gaussian buffers, valid for the rows last projected
        self.means2d = np.zeros((n, 2))
        self.conics = np.zeros((n, 3))
        self.depths = np.zeros(n)
        self.radii = np.zeros(n, np.int32)
        self.rect = np.zeros((n, 4), np.int32)
        self.m2_dt = np.zeros((n, 2), self.dtype)
        self.cn_dt = np.zeros((n, 3), self.dtype)
        self.colors = np.zeros((n, 3), self.dtype)
        if self.sh_degree == 0:  # view-independent: once
            self.colors[:] = _sh.sh_to_color(np.ones((n, 3)), self.sh, 0)[0]
        self._order = None  # depth order of the last whole render (None: sort from scratch)
        self._stamp = np.zeros(n, np.int64)
        self._mark = 0
        self.image = np.zeros((self.height, self.width, 3), self.dtype)
        self._T = np.empty((self.height, self.width), self.dtype)
        self.tiles_blended = 0  # tiles composited in two orders by render_blended
        self._nc = np.empty((self.height, self.width), np.int32)
        self.renders = 0          # calls of render / render_tiles
        self.tiles_rendered = 0   # tiles composited
        self.gaussians_projected = 0

    @property
    def n_gaussians(self) -> int:
        return self.means.shape[0]

    def _viewmat(self, c2w) -> np.ndarray:
        return SplatCamera.from_c2w(c2w, self.cam.fx, self.cam.fy, self.cam.cx, self.cam.cy,
                                    self.width, self.height).validate()

    def _project(self, vm: np.ndarray, idx: np.ndarray | None) -> None:
        c = self.cam
        _proj.project_cov(self.means, self.cov6, vm, c.fx, c.fy, c.cx, c.cy, c.width, c.height,
                          c.near, c.far, idx=idx,
                          out=(self.means2d, self.conics, self.depths, self.radii))
        sel = np.arange(self.n_gaussians) if idx is None else idx
        _finish_subset(sel, self.means2d, self.conics, self.radii, self.opac, self.radius_factor,
                       self.width, self.height, TILE, self.m2_dt, self.cn_dt, self.rect)
        if self.sh_degree > 0 and len(sel):
            campos = -vm[:3, :3].T @ vm[:3, 3]
            dirs = self.means[sel] - campos[None, :]
            self.colors[sel] = _sh.sh_to_color(dirs, self.sh[sel], self.sh_degree)[0]
        self.gaussians_projected += len(sel)

    def render(self, c2w) -> np.ndarray:
        """The whole image at pose ``c2w``: (H, W, 3) of ``dtype`` (a view of an
        internal buffer, overwritten by the next call)."""
        vm = self._viewmat(c2w)
        self._project(vm, None)
        # the lists of bin_gaussians (tested): the tile ranges _finish_subset
        # computed, and the depth order of the last whole render as the start
        # of this one's (the event stage renders poses microseconds apart)
        order = _raster.depth_order((self.radii > 0) & self._binned, self.depths, self._order)
        self._order = order
        offsets, gids = _raster.bin_rects_kernel(order, self.rect[order], self.width, self.height,
                                                 TILE, numba.get_num_threads())
        self._composite(np.arange(self.n_tiles, dtype=np.int64), offsets, gids, self.image)
        self.renders += 1
        self.tiles_rendered += self.n_tiles
        return self.image

    def _composite(self, tiles, offsets, gids, image, gids_b=None, s: float = 0.0) -> None:
        """Composite ``tiles``; ``gids_b``: a second order to cross-fade with
        by ``s`` (:func:`gs2e.splat.raster._make_forward`)."""
        two = () if gids_b is None else (gids_b, float(s))
        _raster.forward_kernel(self.dtype, offsets, self.window, two_orders=bool(two))(
            tiles, offsets, gids, self.m2_dt, self.cn_dt, self.opac_dt, self.colors, self.bg,
            self.width, self.height, TILE, image, self._T, self._nc,
            *_raster.tile_schedule(offsets), *two)

    def depth_order_at(self, c2w) -> np.ndarray:
        """(N,) int64: every Gaussian (culled or not) by increasing camera depth
        of its centre at pose ``c2w``, ties by index (a held order for
        :meth:`render_blended`)."""
        vm = self._viewmat(c2w)
        return np.argsort(self.means @ vm[2, :3] + vm[2, 3], kind="stable").astype(np.int64)

    def _held_lists(self, order_a: np.ndarray, order_b: np.ndarray, s: float):
        """Tile lists of the Gaussians drawn at the last projection, in two
        held orders ((N,) from :meth:`depth_order_at`): (offsets, gids_a,
        gids_b), gids_b gids_a itself where s = 0 (one order)."""
        vis = (self.radii > 0) & self._binned
        orders = [o[vis[o]] for o in ((order_a,) if s == 0.0 else (order_a, order_b))]
        lists = [_raster.bin_rects_kernel(o, self.rect[o], self.width, self.height, TILE,
                                          numba.get_num_threads()) for o in orders]
        return lists[0][0], lists[0][1], lists[-1][1]

    def render_blended(self, c2w, order_a: np.ndarray, order_b: np.ndarray, s: float) -> np.ndarray:
        """The whole image at pose ``c2w`` composited in two held depth orders
        and cross-faded: (1 - s) x the image in ``order_a`` + s x the one in
        ``order_b`` ((N,) from :meth:`depth_order_at` at two poses). One pass:
        a tile whose lists the two orders change is composited in both at once,
        each Gaussian's alphas computed once where both lists hold it at the
        same position (the same bits as two renders blended). With order_a at
        this pose and s = 0 this is :meth:`render`. Returns :attr:`image`
        (overwritten by the next call)."""
        vm = self._viewmat(c2w)
        self._project(vm, None)
        offsets, gids_a, gids_b = self._held_lists(order_a, order_b, s)
        self._composite(np.arange(self.n_tiles, dtype=np.int64), offsets, gids_a, self.image,
                        None if s == 0.0 else gids_b, s)
        self.renders += 1
        self.tiles_rendered += self.n_tiles
        if s != 0.0:
            self.tiles_blended += _differing_tiles(offsets, gids_a, gids_b)
        return self.image

    def render_tangent(self, c2w, dvm: np.ndarray, order_a: np.ndarray, order_b: np.ndarray,
                       s: float, ds: float) -> tuple[np.ndarray, np.ndarray]:
        """The tangent pass (:mod:`gs2e.splat.tangent`; smooth window only):
        the image :meth:`render_blended` composes at pose ``c2w`` with orders
        ``order_a``, ``order_b`` and weight ``s``, and its derivative along
        the view matrix's rate ``dvm`` (4, 4) with the weight's rate ``ds``
        (per the caller's unit of time): ((H, W, 3), (H, W, 3)) float64,
        computed in float64 (:data:`gs2e.splat.raster.raster_tangent_kernel`:
        the image has the bits of a float64 renderer's render_blended outside
        a cross-fade, and equals it to rounding inside one). ValueError for
        the cut window, whose image jumps in time."""
        from gs2e.splat import tangent as _tan

        if self.window != "smooth":
            raise ValueError("render_tangent: the image of the cut window jumps in time; "
                             "its derivative is the smooth window's (splat.window: smooth)")
        vm = self._viewmat(c2w)
        self._project(vm, None)
        offsets, gids_a, gids_b = self._held_lists(order_a, order_b, s)
        drawn = np.flatnonzero((self.radii > 0) & self._binned)
        _, (dm2, dcon, dcol) = _tan.projection_tangent(
            self.means[drawn], self.quats[drawn], self.log_scales[drawn], self.sh[drawn],
            self.sh_degree, self.cam, vm, dvm)
        dgeo = np.zeros((self.n_gaussians, 9))
        dgeo[drawn, 0:2], dgeo[drawn, 2:5], dgeo[drawn, 5:8] = dm2, dcon, dcol
        bg = self.bg.astype(np.float64)
        shape = (self.height, self.width, 3)
        m2, cn, op, col = (self.means2d, self.conics, self.opac, self.colors.astype(np.float64))
        tiles = np.arange(self.n_tiles, dtype=np.int64)
        T, nc = np.empty(shape[:2]), np.empty(shape[:2], np.int32)
        if s != 0.0 and np.array_equal(gids_a, gids_b):  # the orders agree on every tile
            s = 0.0
        out = []
        for gids in ((gids_a,) if s == 0.0 else (gids_a, gids_b)):
            img, dimg = np.zeros(shape), np.zeros(shape)
            _raster.raster_tangent_kernel(tiles, offsets, gids, m2, cn, op, col, bg, self.width,
                                          self.height, TILE, img, T, nc,
                                          *_raster.tile_schedule(offsets), gids, 0.0, dgeo, dimg)
            out.append((img, dimg))
        if s == 0.0:
            return out[0]
        (ia, da), (ib, db) = out
        return ia + s * (ib - ia), da + s * (db - da) + ds * (ib - ia)

    def centres(self, c2w) -> CentreProjection:
        """Projected centres and scales of every Gaussian at pose ``c2w``
        (:func:`image_motion_px`); leaves the render buffers alone. Centres are
        valid up to one image size outside the view."""
        c = self.cam
        n = self.n_gaussians
        B = float(max(self.width, self.height))
        m2, cn, dp, rad = np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.int32)
        _proj.project_cov(self.means, self.cov6, self._viewmat(c2w), c.fx, c.fy, c.cx + B,
                          c.cy + B, c.width + 2 * B, c.height + 2 * B, c.near, c.far,
                          out=(m2, cn, dp, rad))
        self.gaussians_projected += n
        uv = m2 - B
        # centres in the view (10 % margin): the motion of off-screen centres is
        # distorted by the projection's clamp, and near-plane Gaussians far off
        # screen swing by thousands of pixels while their tails barely change
        mx, my = 0.1 * self.width, 0.1 * self.height
        seen = ((rad > 0) & self._binned & (uv[:, 0] >= -mx) & (uv[:, 0] <= self.width + mx)
                & (uv[:, 1] >= -my) & (uv[:, 1] <= self.height + my))
        # largest eigenvalue of the conic (inverse 2D covariance) = 1 / smallest variance
        half_tr = 0.5 * (cn[:, 0] + cn[:, 2])
        lam = half_tr + np.sqrt((0.5 * (cn[:, 0] - cn[:, 2])) ** 2 + cn[:, 1] ** 2)
        sigma = 1.0 / np.sqrt(np.maximum(lam, 1e-300))
        return CentreProjection(uv, np.maximum(sigma, 1.0), rad > 0, seen)

    def candidates(self, c2ws, margin_px: float = 1.0, border_px: float = 16.0) -> TileCandidates:
        """Per tile, the Gaussians that can reach it at the poses ``c2ws`` or
        between consecutive ones.

        Each pose is projected onto the image extended by ``border_px`` on
        every side, so Gaussians just outside the view are seen too; a
        Gaussian's box is the union of its (bin) boxes over the poses, widened
        by ``margin_px`` + the largest displacement of its centre between
        consecutive poses; one that crosses the near plane next to a pose
        where it is visible goes to every tile. This holds while no centre
        moves more than ``border_px`` between consecutive poses outside the
        view. ``TileCandidates.speed_px`` gives the largest displacement per tile and
        ``max_step_px`` a robust size of the motion, for the caller to choose
        the span.
        """
        P = len(c2ws)
        n = self.n_gaussians
        B = float(border_px)
        c = self.cam
        u = np.zeros((P, n))
        v = np.zeros((P, n))
        r = np.zeros((P, n))
        z = np.zeros((P, n))
        m2, cn, dp, rad = np.zeros((n, 2)), np.zeros((n, 3)), np.zeros(n), np.zeros(n, np.int32)
        for p, c2w in enumerate(c2ws):
            _proj.project_cov(self.means, self.cov6, self._viewmat(c2w), c.fx, c.fy, c.cx + B,
                              c.cy + B, c.width + 2 * B, c.height + 2 * B, c.near, c.far,
                              out=(m2, cn, dp, rad))
            vis = (rad > 0) & (self.opac >= _raster.ALPHA_MIN)
            r[p] = np.where(vis, rad * self.radius_factor * (1.0 + 1e-6) + 1e-3, 0.0)
            u[p], v[p], z[p] = m2[:, 0] - B, m2[:, 1] - B, dp
        self.gaussians_projected += P * n
        vis = r > 0
        disp = np.zeros(n)
        everywhere = np.zeros(n, bool)
        if P > 1:
            both = vis[1:] & vis[:-1]
            step = np.hypot(np.diff(u, axis=0), np.diff(v, axis=0))
            disp = np.where(both, step, 0.0).max(axis=0)
            behind = z < c.near
            everywhere = ((vis[:-1] & behind[1:]) | (vis[1:] & behind[:-1])).any(axis=0)
            seen = both.any(axis=0)
        margin = float(margin_px) + disp
        offsets = np.zeros(self.n_tiles + 1, np.int64)
        _cover_kernel(u, v, r, margin, everywhere, self.width, self.height, TILE, True, offsets,
                      np.empty(0, np.int64))
        np.cumsum(offsets, out=offsets)
        gids = np.empty(int(offsets[-1]), np.int64)
        _cover_kernel(u, v, r, margin, everywhere, self.width, self.height, TILE, False, offsets,
                      gids)
        _sort_by_depth(offsets, gids, z[P // 2])
        step_q99 = float(np.quantile(disp[seen], 0.99)) if P > 1 and seen.any() else 0.0
        return TileCandidates(offsets, gids, _tile_speed(offsets, gids, disp), step_q99)

    def render_tiles(self, c2w, tiles: np.ndarray, cand: TileCandidates) -> np.ndarray:
        """Render the tiles ``tiles`` (int64 tile numbers, row-major) at pose
        ``c2w`` into :attr:`image` (other tiles keep their pixels) and return it.
        ``cand`` must cover this pose (see :meth:`candidates`)."""
        tiles = np.ascontiguousarray(tiles, dtype=np.int64)
        self._mark += 1
        idx = _union(tiles, cand.offsets, cand.gids, self._stamp, self._mark)
        self._project(self._viewmat(c2w), idx)
        offsets, gids = _tile_lists(tiles, cand.offsets, cand.gids, self.rect, self.depths,
                                    self.width, TILE)
        self._composite(tiles, offsets, gids, self.image)
        self.renders += 1
        self.tiles_rendered += len(tiles)
        return self.image


# ---------------------------------------------------------------- continuous in time
ORDER_PROBES = 64  # poses probed for the path's largest image-motion rate
ORDER_PROBE_US = 1000  # step over which each probe measures it
# Fraction of each knot interval over which the two held orders cross-fade, centred
# in it; the rest of the interval composites one order, at the cost of a plain
# render. A short fade left the curve clock's renders as they were (the swaps'
# differences are small against its bound) and cut the composites' cost; a quarter
# made the line's error grow slower than h^1.8 on temple_ring (a fade shorter than a
# step acts as a jump), half keeps h^1.87-2.06 on the four scenes: docs/events.md.
ORDER_FADE = 0.5


@dataclass(frozen=True)
class OrderKnots:
    """Times at which a continuous render takes its depth orders: every
    ``dt_us`` from ``t0_us`` (the path's start), so every stage that renders
    the path (sharp frames, blurred frames' sub-frames, events) composes the
    same image at the same time, whatever span it renders. The orders of
    knots j and j + 1 cross-fade over the middle ``fade`` of the interval
    between them (1: all of it)."""

    t0_us: float
    dt_us: float
    fade: float = ORDER_FADE

    def bracket(self, t_us: float) -> tuple[int, float]:
        """(j, s): t_us lies in knot interval [t_j, t_{j+1}] at weight s in
        [0, 1] of order j + 1: 0 before the interval's middle ``fade``, 1
        after it, a smoothstep across it (C1: s' = 0 where it starts and ends)."""
        x = (float(t_us) - self.t0_us) / self.dt_us
        j = int(math.floor(x))
        u = min(1.0, max(0.0, (x - j - 0.5 * (1.0 - self.fade)) / self.fade))
        return j, u * u * (3.0 - 2.0 * u)

    def weight_rate(self, t_us: float) -> float:
        """d s / d t (per us) of :meth:`bracket`'s weight at ``t_us``: the
        smoothstep's 6 u (1 - u) / (fade dt_us) inside the fade, 0 outside."""
        x = (float(t_us) - self.t0_us) / self.dt_us
        u = (x - math.floor(x) - 0.5 * (1.0 - self.fade)) / self.fade
        return 6.0 * u * (1.0 - u) / (self.fade * self.dt_us) if 0.0 < u < 1.0 else 0.0

    def time(self, j: int) -> float:
        return self.t0_us + j * self.dt_us


def order_knots(renderer: "ForwardRenderer", pose_at, t0_us: float, t1_us: float,
                step_px: float, probes: int = ORDER_PROBES, probe_us: int = ORDER_PROBE_US) -> OrderKnots:
    """Knots ``step_px`` of image motion apart at the path's fastest.

    The rate is the largest of ``probes`` measurements of
    :func:`image_motion_px` over ``probe_us``, evenly over [t0_us, t1_us]
    (the whole path: the knots must not depend on the span a stage renders).
    A path with no image motion gets one interval. ``pose_at``: t_us -> c2w.
    """
    if not step_px > 0:
        raise ValueError(f"order_knots: step_px must be > 0, got {step_px}")
    span = float(t1_us - t0_us)
    step = float(min(probe_us, max(span, 1.0)))
    starts = np.linspace(t0_us, max(t0_us, t1_us - step), probes)
    rate = max((image_motion_px(renderer.centres(pose_at(t)), renderer.centres(pose_at(min(t1_us, t + step))))
                for t in starts), default=0.0) / step
    dt = span + 1.0 if rate <= 0.0 else max(1.0, min(span + 1.0, step_px / rate))
    return OrderKnots(float(t0_us), float(dt))


class ContinuousRenderer:
    """A model's image at any time of a path, continuous in time (issue 67).

    With the smooth window (:mod:`gs2e.splat.raster`) a Gaussian no longer
    jumps where its edge crosses a pixel; what is left is the depth order,
    which a render sorts anew at every pose, so two Gaussians that swap
    change a pixel by a jump. Here the order is held at the knots (:class:`OrderKnots`)
    and cross-faded between them: at time t in [t_j, t_{j+1}] the image is
    (1 - s) x the composite in the order of t_j + s x the one in the order of
    t_{j+1} (:meth:`ForwardRenderer.render_blended`, s from
    :meth:`OrderKnots.bracket`: a smoothstep over the middle ``fade`` of the
    interval), both at t's pose; where s is 0 or 1 one order is composited,
    at the cost of a plain render. At a knot it is that pose's ordinary
    render, and it is C1 in time where each fixed-order composite is.

    ``renderer``: a :class:`ForwardRenderer` (its window: the model's);
    ``pose_at``: t_us -> (4, 4) c2w on [knots.t0_us, t1_us] (a knot past the
    path's end takes the end's order).
    """

    def __init__(self, renderer: "ForwardRenderer", pose_at, knots: OrderKnots, t1_us: float):
        self.renderer, self.pose_at, self.knots, self.t1_us = renderer, pose_at, knots, t1_us
        self._orders: dict[int, np.ndarray] = {}

    def _order(self, j: int) -> np.ndarray:
        if j not in self._orders:
            if len(self._orders) > 4:  # renders go forward in time: keep the recent knots
                for old in sorted(self._orders)[:-2]:
                    del self._orders[old]
            t = min(max(self.knots.time(j), self.knots.t0_us), self.t1_us)
            self._orders[j] = self.renderer.depth_order_at(self.pose_at(int(round(t))))
        return self._orders[j]

    def _held(self, t_us: float) -> tuple[np.ndarray, np.ndarray, float]:
        """(order_a, order_b, s) at ``t_us``: the orders to composite and the
        weight of order_b (:meth:`OrderKnots.bracket`; past the fade, s = 1,
        order j + 1 alone)."""
        j, s = self.knots.bracket(t_us)
        if s == 1.0:
            j, s = j + 1, 0.0
        order = self._order(j)
        return order, (order if s == 0.0 else self._order(j + 1)), s

    def render(self, t_us: float) -> np.ndarray:
        """(H, W, 3) image at ``t_us`` (the renderer's buffer)."""
        return self.renderer.render_blended(self.pose_at(t_us), *self._held(t_us))

    def render_tangent(self, t_us: float, h_us: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
        """(image, d image / dt per us) at ``t_us``, both (H, W, 3) float64
        (:meth:`ForwardRenderer.render_tangent`): the image of :meth:`render`
        (to rounding) and its exact derivative. The view matrix's rate is the
        central difference of the path's pose over +-``h_us`` (one-sided at
        the path's ends), exact to O(h_us^2) on the smooth pose curve."""
        lo, hi = max(self.knots.t0_us, t_us - h_us), min(self.t1_us, t_us + h_us)
        if not hi > lo:
            raise ValueError(f"render_tangent: no pose rate at {t_us} us with h_us={h_us} on the path "
                             f"[{self.knots.t0_us}, {self.t1_us}] us")
        r = self.renderer
        dvm = (r._viewmat(self.pose_at(hi)) - r._viewmat(self.pose_at(lo))) / (hi - lo)
        return r.render_tangent(self.pose_at(t_us), dvm, *self._held(t_us), self.knots.weight_rate(t_us))
