"""Event-based 3D reconstruction on the CPU: the paper's Table 1 task.

A 3DGS model is trained from one generated trajectory alone (its events,
blurred frames, poses and intrinsics; never the source photos, model or
points) on gs2e's training loop (:func:`gs2e.splat.optimise.optimise`:
rasterizer, Adam with the trainer's learning rates, density control on the
3DGS schedule, position learning-rate decay, the non-finite guard), each
variant an objective of it:

``event_only``
    EventNeRF's event loss (Rudnev et al., CVPR 2023): two renders at the
    ends of a random window [t_a, t_b] of the stream, compared in log
    luminance with the window's per-pixel sum of signed log steps (the
    simulator's per-pixel thresholds; ON +theta_on, OFF -theta_off):
    ``mean((log(Y_b + eps) - log(Y_a + eps) - sum)^2)`` over the whole image,
    so pixels without events ask for no change (EventNeRF's negative
    samples). Y is linear luminance, eps the event model's dark floor. We
    follow EventNeRF rather than IncEventGS's normalised loss because gs2e's
    windows carry the simulator's exact thresholds: the unnormalised
    difference is the quantity the events measure. A window spans a random
    image motion of ``window_px_max / 8`` to ``window_px_max`` pixels (the
    trajectory's median image speed converts it to time), so every speed
    preset sees windows of the same geometry and the speeds differ only in
    what the sensor does with the motion (EventNeRF draws random window
    lengths too); windows lie anywhere in the simulated span.
``event_blur``
    The same plus a blur term (E2GS / EvDeblurNeRF style): a training
    frame's blurred image is predicted as the linear-light mean of renders
    at poses spread over its exposure, compared with the 3DGS loss (0.8 L1 +
    0.2 D-SSIM) in sRGB, weight ``lambda_blur``. As many renders as the
    frame's motion needs (one per 2 px, at most ``blur_subframes``), at
    ``blur_downscale`` or coarser: a blurred frame holds little detail
    along its motion, and the events carry the fine detail.
``sharp``
    The upper bound: the same trainer on the training frames' sharp images
    at their poses (the 3DGS loss).

Initialisation (no source geometry): ``n_init`` points drawn along random
pixel rays of the training cameras, uniform in inverse depth over
[d / 4, 4 d], kept where at least half the cameras see them (the cameras'
common view volume); d is the distance from the cameras to the point nearest
all their optical axes, or, when the axes do not converge (forward-facing
paths), ten times the cameras' spread. Grey colour, opacity 0.1, scales
from the 3 nearest neighbours (3DGS's rule).

Evaluation: every ``test_every``-th usable frame (offset by half; a smaller
step on short trajectories, so that at least 3 frames are held out) is held
out: its sharp and blurred images are never trained on (its events stay in
the stream, as in EventNeRF's evaluation). On a path travelled back and
forth (``trajectory.min_duration_s``) the frames are held out by position
instead (:func:`split_by_position`): every ``test_every``-th piece of the
path, on every leg; a training frame whose exposure sweeps through a
held-out piece gives ``event_blur`` no blurred image (its sharp image at its
own pose stays a ``sharp`` training frame). Events under a colour filter
(``events.cfa``, ``color_davis346``) supervise each pixel's own channel
(:func:`event_loss`), as EventNeRF's colour training does: the paper's
Table 1 colour rows. Renders at its pose are scored
on luminance (grey events carry no colour) after the literature's per-image
correction for what events cannot observe (Robust e-NeRF / Deblur e-NeRF,
Low & Lee 2023: an affine map of predicted log luminance, a log Y + b,
least-squares fitted to the sharp frame's), applied to every variant alike;
the uncorrected luminance score and the RGB score (``psnr_rgb``: what colour
events or frames teach) are recorded too.

Arrays: images (H, W, 3) float32 sRGB in [0, 1]; times int64 us; poses
camera-to-world (4, 4), OpenCV axes.
"""

from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from gs2e.bench.dataset import Dataset, grey, intrinsics, motion_px, pooled_psnr, score
from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.splat.init import init_from_points
from gs2e.splat.loss import photometric_loss
from gs2e.splat.model import render, to_params
from gs2e.splat.rasterize import SplatCamera
from gs2e.splat.settings import SplatSettings
from gs2e.splat.optimise import Schedule, Step, make_optimizer, optimise, training_dtype
from gs2e.splat.strategy import DensifyConfig, DensifyStrategy
from gs2e.splat.views import downscale_area

log = get_logger("gs2e.bench")

VARIANTS = ("event_only", "event_blur", "sharp")
# position lr 10x the trainer's (3DGS's): Gaussians start at random, far from the surfaces
# (demo base_mild, sharp frames, 1500 steps: +0.6 dB and SSIM 0.73 -> 0.80 against 3DGS's
# rate); the other learning rates are the trainer's defaults (splat.lr_* in the schema)
POSITION_LR = {"lr_position_init": 1.6e-3, "lr_position_final": 1.6e-5}
# one blur sub-frame per this much image motion over the exposure (rendered px)
BLUR_PX_PER_SUBFRAME = 2.0
# poses along an exposure checked against the held-out pieces of a back-and-forth path
EXPOSURE_POSES = 33


@dataclass(frozen=True)
class Recon3dSettings:
    """The ``bench.recon3d_*`` keys, resolved (:func:`recon3d_settings`: the
    schema holds their defaults), and the task's own densification constants."""

    variants: tuple[str, ...]
    steps: int
    n_init: int
    budget: int
    test_every: int
    window_px_max: float
    blur_subframes: int
    blur_downscale: int
    lambda_blur: float
    # [[from_step, downscale factor], ...] as the trainer's coarse-to-fine schedule
    resolution_schedule: tuple
    backend: str  # resolved (gs2e.splat.backend.resolve_backend)
    compute_dtype: str  # auto, float64, float32 (splat.compute_dtype's choices)
    seed: int = 0
    densify_from: int = 300
    densify_every: int = 100
    densify_grad_threshold: float = 2e-4


# bench key -> Recon3dSettings field, with the type it is read as
RECON3D_KEYS = {"recon3d_variants": ("variants", tuple), "recon3d_steps": ("steps", int),
                "recon3d_init_points": ("n_init", int), "recon3d_budget": ("budget", int),
                "recon3d_test_every": ("test_every", int), "recon3d_window_px_max": ("window_px_max", float),
                "recon3d_blur_subframes": ("blur_subframes", int),
                "recon3d_blur_downscale": ("blur_downscale", int),
                "recon3d_lambda_blur": ("lambda_blur", float),
                "recon3d_resolution_schedule": ("resolution_schedule",
                                                lambda v: tuple(tuple(int(x) for x in s) for s in v)),
                "recon3d_backend": ("backend", None), "recon3d_compute_dtype": ("compute_dtype", str)}


def recon3d_settings(bench: dict, seed: int = 0, **over) -> Recon3dSettings:
    """The task's settings from the (validated) ``bench`` section; ``over``
    replaces fields by name (tests use smaller runs)."""
    from gs2e.splat.backend import resolve_backend

    kw = {}
    for key, (name, conv) in RECON3D_KEYS.items():
        kw[name] = (resolve_backend(bench[key], "bench.recon3d_backend") if conv is None
                    else conv(bench[key]))
    return Recon3dSettings(**{**kw, "seed": int(seed), **over})


@dataclass
class Recon3dData:
    """What the trainer may use, and the held-out ground truth."""

    K: np.ndarray  # (3, 3) px
    width: int
    height: int
    pose_at: object  # t_us (Q,) -> c2w (Q, 4, 4)
    span_us: tuple[int, int]  # the events' (and poses') usable span
    us_per_px: float  # the trajectory's median time per pixel of image motion (us)
    ev_t: np.ndarray  # (M,) int64 us, sorted
    ev_pix: np.ndarray  # (M,) int64 y * W + x
    ev_step: np.ndarray  # (M,) float64 signed log step
    log_eps: float
    train_idx: list[int]  # frame indices whose images may be trained on
    test_idx: list[int]
    t_us: np.ndarray  # (F,) frame times
    c2w: np.ndarray  # (F, 4, 4)
    exposure_us: np.ndarray  # (F,)
    motion_px: np.ndarray  # (F,) median image motion over each exposure (px; NaN unknown)
    sharp: dict[int, torch.Tensor]  # train + test frames
    blurred: dict[int, torch.Tensor]  # train frames whose blur may be trained on (when blurred)
    cfa: np.ndarray | None = None  # (H, W) int64 channel of each pixel (colour events); None: luminance


# ------------------------------------------------------------------ losses
def log_luminance(img_srgb: torch.Tensor, eps: float) -> torch.Tensor:
    """(H, W) log(Y + eps), Y the linear luminance of an sRGB render (H, W, 3)."""
    return torch.log(luminance(srgb_to_linear(img_srgb.clamp_min(0.0))) + eps)


def event_loss(img_a: torch.Tensor, img_b: torch.Tensor, step_sum: torch.Tensor, eps: float) -> torch.Tensor:
    """Mean squared difference between the renders' change of log luminance
    from t_a to t_b and the window's per-pixel sum of signed log steps (H, W).
    Colour events (``step_sum`` (H, W, 3), :func:`window_step_sum`): the change
    of each channel's log against that channel's sum, over the entries that
    hold one (a pixel sees its own channel only; NaN elsewhere), as
    EventNeRF's colour training masks each pixel to its channel."""
    if step_sum.ndim == 3:
        d = (torch.log(srgb_to_linear(img_b.clamp_min(0.0)) + eps)
             - torch.log(srgb_to_linear(img_a.clamp_min(0.0)) + eps))
        seen = torch.isfinite(step_sum)
        return ((d - torch.nan_to_num(step_sum)) ** 2)[seen].mean()
    d = log_luminance(img_b, eps) - log_luminance(img_a, eps)
    return ((d - step_sum) ** 2).mean()


def blur_of(renders: list[torch.Tensor]) -> torch.Tensor:
    """The blurred frame of sub-frame renders: their linear-light mean, sRGB-encoded."""
    lin = torch.stack([srgb_to_linear(r.clamp_min(0.0)) for r in renders]).mean(dim=0)
    return linear_to_srgb(lin)


def blur_subframes(motion_px: float, most: int) -> int:
    """Renders that average a frame's exposure: one per BLUR_PX_PER_SUBFRAME of
    its image motion (rendered px), 1 to ``most`` (``most`` when unknown)."""
    if not np.isfinite(motion_px):
        return most
    return int(min(most, max(1, math.ceil(motion_px / BLUR_PX_PER_SUBFRAME))))


def window_step_sum(data: Recon3dData, t_a: float, t_b: float, downscale: int = 1) -> torch.Tensor:
    """(H, W) float32 sum of the signed log steps of the events in (t_a, t_b];
    area-averaged to the size of ``downscale`` (the mean change over each block).
    Colour events (``data.cfa``): (H, W, 3), each channel's mean over the
    block's pixels of that channel, NaN where the block has none (at full
    size, every channel but the pixel's own): the colour survives the blocks."""
    # integer keys: a float key would convert the whole int64 time array per search
    i0 = int(np.searchsorted(data.ev_t, np.int64(np.floor(t_a)), side="right"))
    i1 = int(np.searchsorted(data.ev_t, np.int64(np.floor(t_b)), side="right"))
    acc = np.bincount(data.ev_pix[i0:i1], weights=data.ev_step[i0:i1],
                      minlength=data.width * data.height)
    acc = acc.reshape(data.height, data.width).astype(np.float32)
    if data.cfa is None:
        return torch.from_numpy(downscale_area(acc, downscale))
    out = []
    for c in range(3):
        own = (data.cfa == c).astype(np.float32)
        n = downscale_area(own, downscale)
        with np.errstate(invalid="ignore", divide="ignore"):
            out.append(np.where(n > 0, downscale_area(acc * own, downscale) / n, np.nan))
    return torch.from_numpy(np.stack(out, axis=-1).astype(np.float32))


# ------------------------------------------------------------------ evaluation
def log_affine_fit(pred_y: np.ndarray, gt_y: np.ndarray, eps: float) -> tuple[float, float]:
    """(a, b) minimising sum (a log(pred + eps) + b - log(gt + eps))^2 over pixels."""
    x = np.log(np.asarray(pred_y, np.float64).ravel() + eps)
    y = np.log(np.asarray(gt_y, np.float64).ravel() + eps)
    vx = float(np.var(x))
    if vx < 1e-12:  # a flat render: only the offset is defined
        return 1.0, float(np.mean(y) - np.mean(x))
    a = float(np.mean((x - x.mean()) * (y - y.mean())) / vx)
    return a, float(y.mean() - a * x.mean())


def corrected_luminance(pred_y: np.ndarray, a: float, b: float, eps: float) -> np.ndarray:
    """exp(a log(pred + eps) + b) - eps, clipped to [0, 1]."""
    return np.clip(np.exp(a * np.log(np.asarray(pred_y, np.float64) + eps) + b) - eps, 0.0, 1.0)


def score_view(render_srgb: np.ndarray, sharp_srgb: np.ndarray, eps: float) -> dict[str, float]:
    """Scores of one held-out render (H, W, 3) against its sharp frame: luminance
    after the per-image log-affine correction (psnr, ssim, mse, a, b), luminance
    uncorrected (psnr_raw, mse_raw), colour uncorrected (psnr_rgb) and colour
    after the same correction per channel (psnr_rgb_corrected: what colour
    events can teach, each channel's level and gain being unobservable to
    events as the luminance's are)."""

    y_pred = luminance(srgb_to_linear(np.clip(render_srgb, 0.0, 1.0)))
    y_gt = luminance(srgb_to_linear(sharp_srgb))
    a, b = log_affine_fit(y_pred, y_gt, eps)
    grey_gt = linear_to_srgb(y_gt)[..., None]
    corr = score(linear_to_srgb(corrected_luminance(y_pred, a, b, eps))[..., None], grey_gt)
    raw = score(linear_to_srgb(y_pred)[..., None], grey_gt)
    rgb = score(np.clip(render_srgb, 0.0, 1.0), sharp_srgb)
    pred_c, gt_c = srgb_to_linear(np.clip(render_srgb, 0.0, 1.0)), srgb_to_linear(sharp_srgb)
    rgb_corr = score(linear_to_srgb(np.stack([corrected_luminance(pred_c[..., c], *log_affine_fit(
        pred_c[..., c], gt_c[..., c], eps), eps) for c in range(3)], axis=-1)), sharp_srgb)
    return {**corr, "log_gain": a, "log_offset": b, "psnr_raw": raw["psnr"], "mse_raw": raw["mse"],
            "psnr_rgb": rgb["psnr"], "psnr_rgb_corrected": rgb_corr["psnr"]}


# ------------------------------------------------------------------ initialisation
def look_at_distance(c2w: np.ndarray) -> float | None:
    """Median distance from the cameras to the point nearest all their optical
    axes, or None when the axes do not converge (nearly parallel)."""
    o = c2w[:, :3, 3]
    d = c2w[:, :3, 2] / np.linalg.norm(c2w[:, :3, 2], axis=1, keepdims=True)
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
    A, rhs = P.sum(0), np.einsum("nij,nj->i", P, o)
    w = np.linalg.eigvalsh(A)
    if w[0] < 0.02 * w[-1]:
        return None
    x = np.linalg.solve(A, rhs)
    depth = np.einsum("ni,ni->n", x[None] - o, d)
    if np.median(depth) <= 0:
        return None
    return float(np.median(np.linalg.norm(x[None] - o, axis=1)))


def random_init(c2w: np.ndarray, K: np.ndarray, width: int, height: int, n: int,
                rng: np.random.Generator) -> dict[str, np.ndarray]:
    """``n`` grey Gaussians in the cameras' common view volume (module docstring)."""
    o = c2w[:, :3, 3]
    d0 = look_at_distance(c2w)
    if d0 is None:
        spread = float(np.max(np.linalg.norm(o - o.mean(0), axis=1)))
        d0 = 10.0 * spread if spread > 0 else 1.0
    near, far = d0 / 4, d0 * 4
    w2c = np.linalg.inv(c2w)
    Kinv = np.linalg.inv(K)
    pts: list[np.ndarray] = []
    have = 0
    for _ in range(50):  # rounds of candidates
        m = max(4 * n, 1000)
        cam = rng.integers(0, len(c2w), m)
        pix = np.stack([rng.uniform(0, width, m), rng.uniform(0, height, m), np.ones(m)], 1)
        inv_depth = rng.uniform(1 / far, 1 / near, m)
        x_cam = (pix @ Kinv.T) / inv_depth[:, None]
        x = np.einsum("nij,nj->ni", c2w[cam, :3, :3], x_cam) + o[cam]
        xh = np.concatenate([x, np.ones((m, 1))], 1)
        xc = np.einsum("cij,nj->nci", w2c[:, :3], xh)  # (m, C, 3)
        z = xc[..., 2]
        uv = np.einsum("ij,ncj->nci", K, xc)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = uv[..., 0] / z, uv[..., 1] / z
        seen = (z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
        keep = seen.mean(axis=1) >= 0.5
        pts.append(x[keep])
        have += int(keep.sum())
        if have >= n:
            break
    xyz = np.concatenate(pts)[:n]
    if len(xyz) < 2:
        raise InputError("recon3d: the cameras share no common view volume to initialise Gaussians in")
    return init_from_points(xyz, np.full((len(xyz), 3), 128, np.uint8), sh_degree=0,
                            init_opacity=0.1)


# ------------------------------------------------------------------ training
def _camera(data: Recon3dData, c2w: np.ndarray, downscale: int = 1) -> SplatCamera:
    """The trajectory's camera at ``c2w``, intrinsics scaled to the downscaled size."""
    K = data.K
    w, h = max(1, data.width // downscale), max(1, data.height // downscale)
    sx, sy = w / data.width, h / data.height
    return SplatCamera.from_c2w(c2w, K[0, 0] * sx, K[1, 1] * sy, K[0, 2] * sx, K[1, 2] * sy, w, h)


class _Targets:
    """Frame images at each downscale factor, made on first use."""

    def __init__(self, images: dict[int, torch.Tensor]):
        self.images = images
        self.cache: dict[tuple[int, int], torch.Tensor] = {}

    def get(self, i: int, downscale: int) -> torch.Tensor:
        if downscale == 1:
            return self.images[i]
        key = (i, downscale)
        if key not in self.cache:
            self.cache[key] = torch.from_numpy(np.ascontiguousarray(
                downscale_area(self.images[i].numpy(), downscale)))
        return self.cache[key]


def _extent(c2w: np.ndarray, d_hint: float | None) -> float:
    o = c2w[:, :3, 3]
    r = float(np.max(np.linalg.norm(o - o.mean(0), axis=1)))
    return 1.1 * max(r, 0.1 * (d_hint or 0.0), 1e-6)


class _SharpFrames:
    """Objective ``sharp``: the photometric loss on one random training frame."""

    def __init__(self, data: Recon3dData, rng: np.random.Generator, bg: torch.Tensor,
                 backend: str, dtype: str):
        self.data, self.rng, self.bg = data, rng, bg
        self.render = functools.partial(render, backend=backend, grad_dtype=dtype)
        self.sharp = _Targets(data.sharp)
        self.j = None

    def step(self, p, it: int, downscale: int, sh_degree: int) -> Step:
        d = self.data
        self.j = d.train_idx[int(self.rng.integers(len(d.train_idx)))]
        cam = _camera(d, d.c2w[self.j], downscale)
        img, _, _, meta = self.render(p, cam, self.bg, sh_degree)
        return Step(photometric_loss(img, self.sharp.get(self.j, downscale)), meta, cam)

    def where(self) -> str:
        return f"frame {self.j}"


class _EventWindows:
    """Objectives ``event_only`` and (``blur``) ``event_blur``: the log change
    between renders at the two ends of a random window against the events'
    summed steps in it (:func:`event_loss`); with ``blur``, plus ``lambda_blur``
    x the photometric loss of the blur of sub-frame renders against one random
    blurred training frame."""

    def __init__(self, data: Recon3dData, s: Recon3dSettings, rng: np.random.Generator,
                 bg: torch.Tensor, blur: bool, dtype: str):
        self.data, self.s, self.rng, self.bg, self.blur = data, s, rng, bg, blur
        self.render = functools.partial(render, backend=s.backend, grad_dtype=dtype)
        self.blurred = _Targets(data.blurred)
        self.blur_frames = sorted(data.blurred)
        self.window = (0.0, 0.0)

    def step(self, p, it: int, downscale: int, sh_degree: int) -> Step:
        d, s, bg = self.data, self.s, self.bg
        t_lo, t_hi = d.span_us
        w_us = min(self.rng.uniform(s.window_px_max / 8, s.window_px_max) * d.us_per_px, t_hi - t_lo)
        t_a = self.rng.uniform(t_lo, t_hi - w_us)
        t_b = t_a + w_us
        self.window = (t_a, t_b)
        pose = d.pose_at(np.array([t_a, t_b]))
        cam = _camera(d, pose[1], downscale)
        img_b, _, _, meta = self.render(p, cam, bg, sh_degree)
        img_a = self.render(p, _camera(d, pose[0], downscale), bg, sh_degree)[0]
        loss = event_loss(img_a, img_b, window_step_sum(d, t_a, t_b, downscale), d.log_eps)
        if self.blur:
            j = self.blur_frames[int(self.rng.integers(len(self.blur_frames)))]
            E = float(d.exposure_us[j])
            dsb = max(downscale, s.blur_downscale)
            k = blur_subframes(float(d.motion_px[j]) / dsb, s.blur_subframes)
            ts = d.t_us[j] - E / 2 + (np.arange(k) + 0.5) * E / k
            subs = [self.render(p, _camera(d, c, dsb), bg, sh_degree)[0] for c in d.pose_at(ts)]
            loss = loss + s.lambda_blur * photometric_loss(blur_of(subs), self.blurred.get(j, dsb))
        return Step(loss, meta, cam)

    def where(self) -> str:
        return f"events {self.window[0]:.0f}-{self.window[1]:.0f} us"


def train_variant(variant: str, data: Recon3dData, s: Recon3dSettings,
                  background: torch.Tensor | None = None) -> tuple[dict[str, torch.Tensor], dict]:
    """Train one variant from random Gaussians on the trainer's loop
    (:func:`gs2e.splat.optimise.optimise`); returns (params, stats: steps,
    cpu_s, wall_s, n_gaussians)."""
    if variant not in VARIANTS:
        raise InputError(f"unknown recon3d variant '{variant}' (choose from {', '.join(VARIANTS)})")
    if variant != "event_only" and not data.train_idx:
        raise InputError(f"recon3d {variant}: no training frames")
    if variant == "event_blur" and not data.blurred:
        raise InputError("recon3d event_blur: no blurred training frames (render.write_blur off, or "
                         "every exposure sweeps through a held-out piece of a back-and-forth path)")
    rng = np.random.default_rng(s.seed)
    gen = torch.Generator().manual_seed(s.seed)
    bg = torch.zeros(3) if background is None else background
    train_c2w = data.c2w[data.train_idx] if data.train_idx else data.pose_at(
        np.linspace(*data.span_us, 16))
    p = to_params(random_init(train_c2w, data.K, data.width, data.height, s.n_init, rng))
    extent = _extent(train_c2w, look_at_distance(train_c2w))
    sched = Schedule(s.steps, POSITION_LR["lr_position_init"], POSITION_LR["lr_position_final"],
                     tuple(tuple(x) for x in s.resolution_schedule))
    opt = make_optimizer(SplatSettings.defaults(), sched, extent)
    strategy = DensifyStrategy(DensifyConfig(grad_threshold=s.densify_grad_threshold, budget=s.budget),
                               extent, densify_from=s.densify_from, densify_until=int(0.8 * s.steps),
                               densify_every=s.densify_every, opacity_reset_every=10 ** 9)
    dtype = training_dtype(s.compute_dtype, (data.width, data.height))
    objective = (_SharpFrames(data, rng, bg, s.backend, dtype) if variant == "sharp"
                 else _EventWindows(data, s, rng, bg, variant == "event_blur", dtype))
    c0, w0 = time.process_time(), time.perf_counter()
    optimise(p, opt, strategy, objective, sched, extent, gen, desc=f"recon3d {variant}",
             context=f"recon3d {variant}: ")
    stats = {"steps": s.steps, "cpu_s": time.process_time() - c0, "wall_s": time.perf_counter() - w0,
             "n_gaussians": int(p["means"].shape[0])}
    log.info("recon3d %s: %d steps, %d Gaussians, %.1f CPU-s (%.1f s wall)", variant, s.steps,
             stats["n_gaussians"], stats["cpu_s"], stats["wall_s"])
    return p, stats


def render_view(p: dict[str, torch.Tensor], data: Recon3dData, c2w: np.ndarray,
                background: torch.Tensor | None = None) -> np.ndarray:
    """(H, W, 3) float64 sRGB render of the model at ``c2w``."""
    with torch.no_grad():
        bg = torch.zeros(3) if background is None else background
        img = render(p, _camera(data, c2w), bg, 0)[0]
    return img.double().numpy()


def evaluate(p: dict[str, torch.Tensor], data: Recon3dData, keep: int | None = None) -> list[dict]:
    """Per held-out frame: its index, time and :func:`score_view`; the row of
    frame ``keep`` also holds its ``render`` (H, W, 3)."""
    rows = []
    for i in data.test_idx:
        img = render_view(p, data, data.c2w[i])
        rows.append({"frame": int(i), "t_us": int(data.t_us[i]),
                     **score_view(img, data.sharp[i].double().numpy(), data.log_eps)})
        if i == keep:
            rows[-1]["render"] = img
    return rows


def split_frames(usable: list[int], test_every: int, min_test: int = 3) -> tuple[list[int], list[int]]:
    """(train, test) frame indices: every ``test_every``-th usable frame,
    starting at half that step, is held out; on short trajectories the step
    shrinks (to 2 at least) so that ``min_test`` frames are held out when
    there are enough (a fast preset's few frames would otherwise leave one
    frame to score a speed on)."""
    if test_every <= 0 or len(usable) < 2:
        return list(usable), []
    step = max(2, min(test_every, len(usable) // min_test))
    test = usable[step // 2::step]
    held = set(test)
    return [i for i in usable if i not in held], test


def in_held_out_piece(position: np.ndarray, test_every: int, frames_per_leg: float) -> np.ndarray:
    """Whether each position along one leg (in [0, 1], any shape) lies in a
    held-out piece: the leg is cut into ``n = test_every * max(1,
    round(frames_per_leg / test_every))`` pieces of equal arc length (about
    one frame's travel each) and every ``test_every``-th piece, starting at
    half that step, is held out."""
    n = test_every * max(1, int(round(frames_per_leg / test_every)))
    piece = np.minimum(n - 1, np.floor(np.clip(position, 0.0, 1.0) * n).astype(np.int64))
    return piece % test_every == test_every // 2


def split_by_position(usable: list[int], position: np.ndarray, test_every: int,
                      frames_per_leg: float) -> tuple[list[int], list[int]]:
    """(train, test) frame indices of a path travelled back and forth: a frame
    whose pose lies in a held-out piece (:func:`in_held_out_piece`) is held
    out, on every leg. So no sharp training image is taken inside a held-out
    piece on any leg (an every-n-th rule would hold out frames whose poses
    the other legs' training frames revisit).

    Parameters
    ----------
    usable : frame indices.
    position : (len(usable),) each frame's position along one leg, in [0, 1].
    test_every : one held-out piece in this many.
    frames_per_leg : frames one leg spans (its duration x the frame rate).
    """
    if test_every <= 0 or len(usable) < 2:
        return list(usable), []
    held = in_held_out_piece(np.asarray(position), test_every, frames_per_leg)
    return ([i for i, h in zip(usable, held) if not h], [i for i, h in zip(usable, held) if h])


# ------------------------------------------------------------------ the task
def recon3d_data(ds: Dataset, settings) -> "object":
    """The trajectory's training data and held-out frames (gs2e.bench.recon3d)."""
    from gs2e.bench.deblur import log_steps

    f, ev, traj = ds.frames, ds.events, ds.trajectory
    t = f["t_us"].to_numpy(np.int64)
    E = f["exposure_us"].to_numpy(np.float64)
    lo = max(ds.sim_span_us[0], int(traj.t_us[0]))
    hi = min(ds.sim_span_us[1], int(traj.t_us[-1]))
    has_blur = bool((E > 0).any()) and (ds.frames_dir / "blur").is_dir()
    half = E / 2 if has_blur else np.zeros_like(E)
    usable = [int(i) for i in np.flatnonzero((t - half >= lo) & (t + half <= hi))]
    if len(usable) < 2 or hi - lo <= 0:
        raise InputError(f"{ds.frames_dir}: recon3d needs at least 2 frames inside the simulated "
                         f"events ({ds.sim_span_us[0]}..{ds.sim_span_us[1]} us), found {len(usable)}")
    blur_train = None
    if len(traj.turns_us) and traj.meta.get("leg_duration_us"):
        # back and forth: hold out by position, so that no leg trains where another is scored
        L, s0 = float(traj.s.max() - traj.s.min()), float(traj.s.min())

        def position(times):  # along one leg, in [0, 1]
            return (traj.arc_length_at(times) - s0) / max(L, 1e-300)

        fps = 1e6 / float(np.median(np.diff(t))) if len(t) > 1 else 1.0
        per_leg = float(traj.meta["leg_duration_us"]) * 1e-6 * fps
        train, test = split_by_position(usable, position(t[usable]), settings.test_every, per_leg)
        if has_blur and test:
            # a blurred frame whose exposure sweeps through a held-out piece would show
            # the held-out views (smeared): not trained on (EXPOSURE_POSES poses checked)
            u = np.linspace(-0.5, 0.5, EXPOSURE_POSES)
            ts = np.clip(t[train, None] + E[train, None] * u[None], lo, hi)
            swept = in_held_out_piece(position(ts.ravel()), settings.test_every,
                                      per_leg).reshape(ts.shape).any(axis=1)
            blur_train = [i for i, sw in zip(train, swept) if not sw]
    else:
        train, test = split_frames(usable, settings.test_every)
    if not test:
        raise InputError(f"{ds.frames_dir}: recon3d holds out no frame (bench.recon3d_test_every)")
    H, W = ds.shape
    i0, i1 = np.searchsorted(ev.t, [lo, hi], side="right")
    x, y = ev.x[i0:i1].astype(np.int64), ev.y[i0:i1].astype(np.int64)
    steps = log_steps(ev.p[i0:i1], x, y, ds.theta_on, ds.theta_off)
    sharp = {i: torch.from_numpy(np.asarray(ds.image("rgb", i), np.float32)) for i in train + test}
    blurred = ({i: torch.from_numpy(np.asarray(ds.image("blur", i), np.float32))
                for i in (train if blur_train is None else blur_train)} if has_blur else {})
    c2w = np.stack([np.asarray(c, np.float64) for c in f["c2w"]])
    motion = np.array([motion_px(f.iloc[i]) for i in range(len(f))], np.float64)
    speed = motion[usable] / np.maximum(E[usable], 1.0)  # px per us over each exposure
    speed = speed[np.isfinite(speed) & (speed > 0) & (E[usable] > 0)]
    # without motion figures (no exposure): a window of window_px_max spans ~2 frames
    us_per_px = (1.0 / float(np.median(speed)) if speed.size else
                 2.0 * float(np.median(np.diff(t))) / settings.window_px_max if len(t) > 1
                 else float(hi - lo) / settings.window_px_max)
    cfa = None
    if ds.cfa is not None:  # colour events: each pixel's own channel (gs2e.events.sampling.image_cfa)
        from gs2e.events.sampling import cfa_channels

        cfa = np.ascontiguousarray(cfa_channels(ds.cfa)[np.arange(H)[:, None] % 2, np.arange(W)[None, :] % 2])
    return Recon3dData(intrinsics(f, 0), W, H, traj.pose_at, (lo, hi), us_per_px, ev.t[i0:i1],
                       y * W + x, steps, ds.log_eps, train, test, t, c2w, E, motion, sharp, blurred, cfa)


def run(ds: Dataset, cfg, user: dict[str, Callable]):
    """Rows of the recon3d task (one per variant x held-out frame) and the
    middle held-out frame's corrected luminance per variant."""
    if user:
        log.warning("recon3d: user methods (%s) apply to the deblur and video tasks only; not run",
                    ", ".join(user))
    s = cfg.recon3d
    data = recon3d_data(ds, s)
    f = ds.frames
    t_first = int(f["t_us"].iloc[data.train_idx[0] if data.train_idx else 0])
    example = data.test_idx[len(data.test_idx) // 2]
    log.info("recon3d: %d training frames (%d with their blur), %d held out, %d events over %.2f s",
             len(data.train_idx), len(data.blurred), len(data.test_idx), len(data.ev_t),
             (data.span_us[1] - data.span_us[0]) * 1e-6)
    rows, shown = [], {}
    for variant in s.variants:
        p, st = train_variant(variant, data, s)
        for r in evaluate(p, data, keep=example):
            img = r.pop("render", None)
            i = r["frame"]
            rows.append({"method": variant, **r, "t_rel_s": (r["t_us"] - t_first) * 1e-6,
                         "motion_px": motion_px(f.iloc[i]), "n_events": len(data.ev_t), "theta": math.nan,
                         "time_s": st["wall_s"], "cpu_s": st["cpu_s"], "steps": st["steps"],
                         "n_gaussians": st["n_gaussians"], "n_train_frames": len(data.train_idx)})
            if img is not None:
                y = luminance(srgb_to_linear(np.clip(img, 0, 1)))
                shown[variant] = linear_to_srgb(corrected_luminance(
                    y, r["log_gain"], r["log_offset"], data.log_eps))
    shown["sharp"] = grey(ds.image("rgb", example))[..., 0]
    return rows, shown, example


def summary(g, row: dict) -> None:
    """The recon3d task's columns of a dataset-table row (:mod:`gs2e.bench.summary`)."""
    row["psnr_raw"] = pooled_psnr(g["mse_raw"].to_numpy(np.float64))
    for key in ("psnr_rgb", "psnr_rgb_corrected"):  # pooled over the views (mean MSE)
        if key in g:
            row[key] = float(-10.0 * np.log10(np.mean(10.0 ** (-g[key].to_numpy(np.float64) / 10.0))))
    row["cpu_min"] = float(g["cpu_s"].iloc[0]) / 60.0
    row["n_gaussians"] = int(g["n_gaussians"].iloc[0])
