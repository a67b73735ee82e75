"""The video task: direct integration and a complementary filter of the
events after one keyframe (:mod:`gs2e.bench.video`), the learned PIE-Net and
PIE-Net-Lite from a reset state at the keyframe (:mod:`gs2e.bench.learned`,
``bench.video_learned``), a user's methods, and ``keyframe_held`` (the
keyframe itself: the reference the events have to beat),
scored on grey (luminance, sRGB-encoded) against the sharp frames: events
carry no colour."""

from __future__ import annotations

import itertools
import math
from typing import Callable, Iterator

import numpy as np

from gs2e.bench import methods as M
from gs2e.bench.dataset import (Dataset, grey, intrinsics, motion_px, score, slice_events,
                                timed)
from gs2e.bench.learned import reconstruct_learned, robust_normalize
from gs2e.bench.video import KEYFRAME_HELD, reconstruct
from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear
from gs2e.common.errors import InputError
from gs2e.common.progress import progress


def video_frames(ds: Dataset, key: int, every: int) -> list[int]:
    """Frames after the keyframe up to the end of the simulated events."""
    t = ds.frames["t_us"].to_numpy()
    if not 0 <= key < len(t) - 1:
        raise InputError(f"bench.video_keyframe: frame {key} is not followed by another frame "
                         f"({ds.frames_dir} has {len(t)} frames)")
    s0, s1 = ds.sim_span_us
    if not s0 <= t[key] <= s1:
        raise InputError(f"{ds.frames_dir}: the keyframe {key} (t = {t[key]} us) lies outside the "
                         f"simulated events ({s0}..{s1} us)")
    out = [i for i in range(key + 1, len(t)) if t[i] <= s1 and (i - key) % every == 0]
    if not out:
        raise InputError(f"{ds.frames_dir}: no frame after the keyframe {key} within the "
                         f"simulated events ({s0}..{s1} us)")
    return out


def run(ds: Dataset, cfg, user: dict[str, Callable]):
    """Rows of the video task and the last scored frame's images per method."""
    from gs2e.bench.deblur import log_steps

    f, ev = ds.frames, ds.events
    key = cfg.video_keyframe
    idx = video_frames(ds, key, cfg.eval_every)
    t_key = int(f["t_us"].iloc[key])
    keyframe = ds.image("rgb", key)
    key_lum = luminance(srgb_to_linear(keyframe))
    steps = log_steps(ev.p, ev.x, ev.y, ds.theta_on, ds.theta_off)
    q = f["t_us"].to_numpy()[idx]
    gens = {"integrate": reconstruct(key_lum, ds.log_eps, ev.t, ev.x, ev.y, steps, t_key, q, 0.0),
            "complementary": reconstruct(key_lum, ds.log_eps, ev.t, ev.x, ev.y, steps, t_key, q,
                                         cfg.video_cf_alpha_rad_s)}
    for name in cfg.video_learned:  # grey, sRGB-encoded already (scored after robust_normalize)
        gens[name] = _at_frames(reconstruct_learned(name, ev, ds.shape, f["t_us"].to_numpy()[key:idx[-1] + 1]),
                                key, idx)
    gens[KEYFRAME_HELD] = itertools.repeat(key_lum)  # linear, as the model-free outputs
    i_key = int(np.searchsorted(ev.t, t_key, side="right"))
    K = intrinsics(f, 0)
    rows, shown = [], {}
    for i in progress(idx, desc="video"):
        r = f.iloc[i]
        t = int(r["t_us"])
        i1 = int(np.searchsorted(ev.t, t, side="right"))
        target = grey(ds.image("rgb", i))
        outs = {}
        for name, g in gens.items():
            img, dt = timed(next, g)
            img = robust_normalize(img) if name in cfg.video_learned else linear_to_srgb(img)
            outs[name] = (img[..., None], dt)
        if user:
            inp = M.BenchInput("video", i, t, slice_events(ev, i_key, i1), t_key, t, np.asarray(r["c2w"]),
                               K, ds.theta_on, ds.theta_off, ds.log_eps,
                               float(r["exposure_us"]), keyframe=keyframe, keyframe_t_us=t_key)
            for name, fn in user.items():
                img, dt = timed(fn, inp)
                outs[name] = (grey(M.as_srgb01(img, ds.shape, f"method {name}")), dt)
        for name, (img, dt) in outs.items():
            rows.append({"method": name, "frame": i, "t_us": t, "t_rel_s": (t - t_key) * 1e-6,
                         "motion_px": motion_px(r), "n_events": i1 - i_key, **score(img, target),
                         "theta": math.nan, "time_s": dt})
            if i == idx[-1]:
                shown[name] = img[..., 0]
        if i == idx[-1]:
            shown["sharp"] = target[..., 0]
    return rows, shown, idx[-1]


def _at_frames(gen: Iterator[np.ndarray], key: int, idx: list[int]) -> Iterator[np.ndarray]:
    """The outputs of ``gen`` (one per frame after the keyframe ``key``) at the
    frames ``idx`` only: a recurrent method steps through every frame."""
    want = set(idx)
    for i, img in enumerate(gen, start=key + 1):
        if i in want:
            yield img


VIDEO_AT_S = 0.5  # the dataset table's psnr_at_0_5s


def summary(g, row: dict) -> None:
    """The video task's columns of a dataset-table row (:mod:`gs2e.bench.summary`)."""
    mse = g["mse"].to_numpy(np.float64)
    t = g["t_rel_s"].to_numpy(np.float64)
    per = -10.0 * np.log10(np.maximum(mse, 1e-20))
    j = int(np.argmin(np.abs(t - VIDEO_AT_S)))
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    row["psnr_at_0_5s"] = float(per[j]) if abs(t[j] - VIDEO_AT_S) <= max(step, 1e-9) else math.nan
    row["psnr_end"] = float(per[-1])
    row["drift_db_per_s"] = float(np.polyfit(t, per, 1)[0]) if len(t) > 2 else math.nan
