"""The deblur task: EDI with the simulator's thresholds (oracle) and with one
chosen per frame, the blurred input, and a user's methods, scored in sRGB
colour (and luminance) against the sharp frame at the same time. Frames whose
exposure the trajectory's ends cut short, or whose window the events do not
cover, are not scored."""

from __future__ import annotations

import math
from typing import Callable

import numpy as np

from gs2e.bench import methods as M
from gs2e.bench.dataset import (Dataset, grey, intrinsics, motion_px, score, slice_events,
                                timed)
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger
from gs2e.common.progress import progress

log = get_logger("gs2e.bench")


def deblur_frames(ds: Dataset, every: int) -> list[int]:
    """Frames the deblur task scores: a blurred frame whose whole exposure lies
    inside the trajectory and the simulated events. None (empty) where no exposure
    fits inside the trajectory at all (a path shorter than one exposure, as
    auto-exposure makes at night: a valid run with nothing to score);
    InputError where exposures fit but the events do not cover them."""
    w, f = ds.windows, ds.frames
    E = f["exposure_us"].to_numpy(np.float64)
    t = f["t_us"].to_numpy(np.float64)
    whole = (t - E / 2 >= t[0]) & (t + E / 2 <= t[-1]) & (E > 0)
    if not whole.any():
        return []
    ok = whole & w["exp_covered"].to_numpy(bool)
    out = [i for i in np.flatnonzero(ok) if i % every == 0]
    if not out:
        raise InputError(f"{ds.frames_dir}: no blurred frame has its whole exposure inside the "
                         f"simulated events ({ds.sim_span_us[0]}..{ds.sim_span_us[1]} us) and "
                         "the trajectory: nothing to deblur")
    return out


def run(ds: Dataset, cfg, user: dict[str, Callable]):
    """Rows of the deblur task and the example frame's images per method."""
    rows, f, w = [], ds.frames, ds.windows
    idx = deblur_frames(ds, cfg.eval_every)
    if not idx:
        log.warning("%s: no blurred frame's whole exposure lies inside the trajectory (%.1f ms long): "
                    "nothing to deblur, no rows", ds.frames_dir,
                    (int(f["t_us"].iloc[-1]) - int(f["t_us"].iloc[0])) * 1e-3)
        return [], {}, None
    t_first = int(f["t_us"].iloc[0])
    theta_med = float(np.median(np.concatenate([ds.theta_on.ravel(), ds.theta_off.ravel()])))
    example = idx[len(idx) // 2]
    shown: dict[str, np.ndarray] = {}
    K = intrinsics(f, 0)
    for i in progress(idx, desc="deblur"):
        r = f.iloc[i]
        E = float(r["exposure_us"])
        ev = slice_events(ds.events, int(w["exp_i0"].iloc[i]), int(w["exp_i1"].iloc[i]))
        blur = ds.image("blur", i)
        inp = M.BenchInput(
            "deblur", i, int(r["t_us"]), ev, int(w["exp_t0_us"].iloc[i]), int(w["exp_t1_us"].iloc[i]),
            np.asarray(r["c2w"]), K, ds.theta_on, ds.theta_off, ds.log_eps, E, blur,
            ds.image("blur", i - 1) if i > 0 else None,
            ds.image("blur", i + 1) if i + 1 < len(f) else None)
        # EDI integrates over the exact exposure [t - E/2, t + E/2]
        inp = _with_exact_exposure(inp)
        sharp = ds.image("rgb", i)
        outs: dict[str, tuple[np.ndarray, float, float]] = {}
        img, dt = timed(M.blurred, inp)
        outs["blurred"] = (img, math.nan, dt)
        img, dt = timed(M.edi_oracle, inp)
        outs["edi_oracle"] = (img, theta_med, dt)
        j = _partner(i, idx)
        span = None
        if j is not None:
            lo, hi = sorted((float(f["t_us"].iloc[i]), float(f["t_us"].iloc[j])))
            span = slice_events(ds.events, int(np.searchsorted(ds.events.t, lo - E / 2, "left")),
                          int(np.searchsorted(ds.events.t, hi + E / 2, "right")))
        (img, th), dt = timed(M.edi_chosen, inp, cfg.deblur,
                               None if j is None else ds.image("blur", j),
                               None if j is None else int(f["t_us"].iloc[j]), span)
        outs["edi_chosen"] = (img, th, dt)
        for name, fn in user.items():
            img, dt = timed(fn, inp)
            outs[name] = (M.as_srgb01(img, ds.shape, f"method {name}"), math.nan, dt)
        for name, (img, th, dt) in outs.items():
            img = img if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)
            on_grey = score(grey(img), grey(sharp))
            rows.append({"method": name, "frame": i, "t_us": int(r["t_us"]),
                         "t_rel_s": (int(r["t_us"]) - t_first) * 1e-6,
                         "motion_px": motion_px(r), "n_events": len(ev), **score(img, sharp),
                         "psnr_grey": on_grey["psnr"], "mse_grey": on_grey["mse"],
                         "theta": th, "time_s": dt})
            if i == example:
                shown[name] = img
        if i == example:
            shown["sharp"] = sharp
    return rows, shown, example


def _partner(i: int, scored: list[int]) -> int | None:
    """The neighbouring scored frame EDI's threshold search pairs frame i with:
    the next one, else the previous one (both exposures whole and simulated)."""
    ok = set(scored)
    return i + 1 if i + 1 in ok else (i - 1 if i - 1 in ok else None)


def _with_exact_exposure(inp: M.BenchInput) -> M.BenchInput:
    from dataclasses import replace

    half = inp.exposure_us / 2
    return replace(inp, t0_us=inp.t_us - half, t1_us=inp.t_us + half)
