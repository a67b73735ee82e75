"""The optical-flow task: flow between consecutive frames from the events
between them, scored against the ground truth of the rendered depth and the
trajectory (:mod:`gs2e.groundtruth.flow`).

Methods: ``zero`` (no motion: the floor every method has to beat) and
``contrast_max`` (:func:`gs2e.bench.flow.contrast_maximisation`, events
only), plus a user's methods (``bench.methods``; a method gets the window's
events as ``BenchInput`` and returns (H, W, 2) px). Scores per frame pair
(every ``bench.eval_every``-th whose events were simulated, at most
``bench.flow_max_pairs`` of them evenly spread over the trajectory): average endpoint
error ``aee_px`` and the share of pixels more than 3 px off ``out_3px`` over
the pixels with valid ground truth (opaque, forward-backward consistent), and
``aee_px_events`` over those of them with an event in the window (the
sparse convention of MVSEC's evaluations). PSNR, SSIM and MSE do not apply
(null).
"""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from gs2e.bench import methods as M
from gs2e.bench.dataset import Dataset, intrinsics, motion_px, slice_events, timed
from gs2e.bench.flow import CMSettings, contrast_maximisation, flow_colour, flow_errors
from gs2e.common.errors import InputError
from gs2e.common.progress import progress
from gs2e.groundtruth.flow import flow_pair

NO_IMAGE_SCORE = {"psnr": math.nan, "ssim": math.nan, "mse": math.nan}


def flow_windows(ds: Dataset, every: int, max_pairs: int | None) -> list[int]:
    """Frames i >= 1 whose window [t_{i-1}, t_i) the events cover, every
    ``every``-th, and at most ``max_pairs`` of those, evenly spread."""
    cov = ds.windows["inter_covered"].to_numpy(bool)
    out = [i for i in range(1, len(cov)) if cov[i] and (i - 1) % every == 0]
    if not out:
        raise InputError(f"{ds.frames_dir}: no pair of consecutive frames whose events were simulated")
    if max_pairs is not None and len(out) > max_pairs:
        out = [out[k] for k in np.unique(np.linspace(0, len(out) - 1, max_pairs).round().astype(int))]
    return out


def run(ds: Dataset, cfg, user: dict[str, Callable]):
    """Rows of the flow task, and the example frame's flows as images."""
    f, ev = ds.frames, ds.events
    idx = flow_windows(ds, cfg.eval_every, cfg.flow_max_pairs)
    K = intrinsics(f, 0)
    H, W = ds.shape
    st = CMSettings()
    rows, shown = [], {}
    example = idx[len(idx) // 2]
    t_first = int(f["t_us"].iloc[0])
    for i in progress(idx, desc="flow"):
        a, b = f.iloc[i - 1], f.iloc[i]
        t0, t1 = int(a["t_us"]), int(b["t_us"])
        gt = flow_pair(ds.depth(i - 1), ds.alpha(i - 1), ds.depth(i), ds.alpha(i), K,
                       np.asarray(a["c2w"]), np.asarray(b["c2w"]))
        i0, i1 = int(ds.windows["inter_i0"].iloc[i]), int(ds.windows["inter_i1"].iloc[i])
        win = slice_events(ev, i0, i1)
        has_event = np.zeros((H, W), bool)
        has_event[win.y, win.x] = True
        outs = {"zero": (np.zeros((H, W, 2)), 0.0)}
        outs["contrast_max"] = timed(contrast_maximisation, win.x, win.y, win.t, t0, t1, W, H, st)
        if user:
            inp = M.BenchInput("flow", i - 1, t0, win, t0, t1, np.asarray(a["c2w"]), K, ds.theta_on,
                               ds.theta_off, ds.log_eps, 0.0)
            for name, fn in user.items():
                flow, dt = timed(fn, inp)
                flow = np.asarray(flow, np.float64)
                if flow.shape != (H, W, 2):
                    raise InputError(f"method {name}: returned flow of shape {flow.shape}, not {(H, W, 2)}")
                outs[name] = (flow, dt)
        for name, (flow, dt) in outs.items():
            err = flow_errors(flow, gt.forward, gt.forward_valid)
            sparse = flow_errors(flow, gt.forward, gt.forward_valid & has_event)
            rows.append({"method": name, "frame": i - 1, "t_us": t0, "t_rel_s": (t0 - t_first) * 1e-6,
                         "motion_px": motion_px(a), "n_events": i1 - i0, **NO_IMAGE_SCORE,
                         "theta": math.nan, "time_s": dt, **err, "aee_px_events": sparse["aee_px"]})
        if i == example:
            scale = float(np.nanpercentile(np.linalg.norm(gt.forward, axis=-1), 99)) \
                if np.isfinite(gt.forward).any() else 1.0
            shown["sharp"] = ds.image("rgb", i - 1)
            gt_img = flow_colour(np.where(gt.forward_valid[..., None], gt.forward, np.nan), scale)
            shown["ground truth"] = gt_img
            for name, (flow, _) in outs.items():
                shown[name] = flow_colour(flow, scale)
    return rows, shown, example - 1


def summary(g, row: dict) -> None:
    """The flow task's columns of a dataset-table row (:mod:`gs2e.bench.summary`):
    aee_px, out_3px and aee_px_events, means over the scored frame pairs."""
    for k in ("aee_px", "out_3px", "aee_px_events"):
        v = g[k].to_numpy(np.float64)
        row[k] = float(np.nanmean(v)) if np.isfinite(v).any() else math.nan
