"""EventNeRF (r00tman/EventNeRF, ``data_loader_split.py``) layout.

What its loader reads, per split ``train``, ``validation``, ``test``::

    <scene>/<split>/pose/NNNNNN.txt        4x4 camera-to-world, OpenCV axes (x right,
                                           y down, z forward), scene inside the unit sphere
    <scene>/<split>/intrinsics/NNNNNN.txt  4x4 (fx, fy, cx, cy; pixel centres +0.5); an
                                           optional 5th row k1 k2 0 0 is not written (= 0)
    <scene>/<split>/rgb/NNNNNN.png         one image per pose (sorted names pair them)
    <scene>/<split>/events/events.npz      exactly one file: x, y (int16), t (float64),
                                           p (int8, -1 OFF / +1 ON)

Splits: validation and test are the same held-out views, every
``eventnerf_holdout_every``-th exported frame (positions h - 1, 2h - 1, ..
strictly between the first and the last frame); train is every other frame,
so no held-out pose or image is ever a training view.

Lead-in: a non-cycled split builds ray samplers for views 1 + max_winsize ..
N - 1 only (data_loader_split.py L86-87; max_winsize = winsize for train, 1 for
validation and test: ddp_train_nerf.py L440-451, ddp_test_nerf.py L54-59).
Each split therefore starts with copies of its first view (same pose,
intrinsics and image: the camera at rest before it moves, so no events):
``winsize`` copies in train, so that every training frame from the second on
ends a window (a window reaching into the lead-in starts at the first frame),
and 2 in validation and test, so that every held-out view is a sampler.

Time axis: the loader places view i of a split at i / (N - 1) * t.max() and
takes the events of [start, end) with ``np.searchsorted`` (data_loader_split.py
L101-124); a window's polarities are summed without their times
(nerf_sample_ray_split.py L287-290). gs2e places view i at i x the exported
frames' mean interval (float64 seconds, lead-in first) and rescales each event
linearly from its interval between two consecutive real views onto the
loader's window (clipped into its float64 bounds), and the file ends with one
zero-polarity event at the last view's time, which sets t.max() and lies in no
window. Every loader window of 1 .. winsize views then holds exactly gs2e's
events between the two views' frames, whatever their spacing (held-out
frames, the trajectory's off-grid last frame). It hard-codes H, W = 260, 346:
frames of another size are an error unless ``eventnerf_fit`` crops or pads
them onto the 346x260 sensor (padded pixels have no events, which EventNeRF
reads as "no brightness change").

``eventnerf.txt`` holds the config keys the layout needs: ``testskip = 1``
(the default 8 would drop views; ddp_train_nerf.py L446-447, L673),
``is_cycled = False`` and ``winsize``: ``eventnerf_winsize``, or
min(50, N - 1) for N training frames.

Poses are normalised as NeRF++ does (EventNeRF renders only inside the unit
sphere): centre = mean camera centre, radius = 1.1 x the largest distance to a
camera or to 99.9 % of the surface points the frames see. Train on the result
with ``polarity_offset = 0`` and ``is_colored = False`` for luminance events,
``is_colored = True`` for events simulated under an RGGB colour filter
(``events.cfa``, the ``color_davis346`` sensor): EventNeRF's colour loader
masks each pixel to its channel with R at even rows and columns
(nerf_sample_ray_split.py), so the pattern must be RGGB and a crop or pad
must move the image by an even number of pixels (else an error);
``eventnerf.txt`` lists these settings.
"""

from __future__ import annotations

import numpy as np

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events
from gs2e.export.common import (ExportOut, SensorFit, check_increasing_bounds, matrix_text, scene_points,
                                unit_sphere)
from gs2e.export.conventions import signed_polarity
from gs2e.export.settings import ExportSettings

SENSOR_W, SENSOR_H = 346, 260  # data_loader_split.py L137: H, W = 260, 346
SPLITS = ("train", "validation", "test")
EVAL_MAX_WINSIZE = 1  # validation / test are loaded with max_winsize = 1 (ddp_train_nerf.py L447)
WINSIZE_CAP = 50  # EventNeRF's configs/nerf/*.txt and configs/ablation/full.txt: winsize = 50


def intrinsics_matrix(K: np.ndarray) -> np.ndarray:
    """EventNeRF's 4x4 intrinsics file content."""
    out = np.eye(4)
    out[:3, :3] = K
    return out


def split_frames(frames: np.ndarray, holdout_every: int) -> dict[str, np.ndarray]:
    """validation = test = the held-out frames (positions holdout_every - 1,
    2 holdout_every - 1, .. strictly inside), train = the others; all three are
    every frame when none can be held out (fewer than 3 frames)."""
    if holdout_every < 2:
        raise ConfigError(f"export.eventnerf_holdout_every = {holdout_every} holds out every frame: "
                          "use at least 2")
    pos = np.arange(holdout_every - 1, len(frames) - 1, holdout_every)
    if len(pos) == 0:
        return {"train": frames, "validation": frames, "test": frames}
    held = frames[pos]
    return {"train": np.delete(frames, pos), "validation": held, "test": held}


def lead_in(split: str, winsize: int) -> int:
    """Copies of a split's first view written before it: the loader's first
    sampler is view 1 + max_winsize (L86), which is then the second training
    frame (train) or the first held-out view (validation, test)."""
    return winsize if split == "train" else 1 + EVAL_MAX_WINSIZE


def loader_bounds_s(n_views: int, t_max_s: float) -> np.ndarray:
    """The loader's window boundaries of a split with ``n_views`` poses:
    (i / (N - 1)) * t.max() in float64, as data_loader_split.py L102-124
    computes them (a Python float times a numpy float64)."""
    return np.array([i / (n_views - 1) for i in range(n_views)]) * np.float64(t_max_s)


def choose_winsize(n_train_frames: int, winsize: int | None) -> int:
    """``winsize`` for a train split of ``n_train_frames`` frames (after its
    lead-in every frame from the second on ends a window of 1 .. winsize
    views): ``None`` picks min(50, N - 1); a window cannot span more than the
    N - 1 intervals."""
    if winsize is None:
        return max(1, min(WINSIZE_CAP, n_train_frames - 1))
    if winsize > n_train_frames - 1:
        raise ConfigError(f"export.eventnerf_winsize = {winsize} is longer than the EventNeRF train split "
                          f"({n_train_frames} frames, {n_train_frames - 1} intervals); use at most "
                          f"{n_train_frames - 1} (or null to choose)")
    return int(winsize)


def loader_times_s(t_us: np.ndarray, t_views_us: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """float64 loader times of events (int us): an event of [t_views_us[k-1],
    t_views_us[k]) is rescaled linearly onto [bounds[k-1], bounds[k]) and
    clipped into it, so the loader's ``searchsorted`` windows hold exactly
    these events. Every event must lie in [t_views_us[0], t_views_us[-1])."""
    t = np.asarray(t_us, np.int64)
    tv = np.asarray(t_views_us, np.int64)
    k = np.searchsorted(tv, t, side="right")  # t_{k-1} <= t < t_k
    if t.size and (k.min() < 1 or k.max() > len(tv) - 1):
        raise ValueError("events outside the split's views' span")
    lo, hi = bounds[k - 1], bounds[k]
    s = lo + (t - tv[k - 1]) / (tv[k] - tv[k - 1]) * (hi - lo)
    return np.minimum(np.maximum(s, lo), np.nextafter(hi, -np.inf))


def loader_events(ev: Events, t_views_us: np.ndarray, lead: int, step_s: float,
                  where: str) -> dict[str, np.ndarray]:
    """events.npz arrays of one split whose real views (after ``lead`` lead-in
    copies) are at ``t_views_us``: view i of the split at i * ``step_s``
    seconds, events rescaled into their windows (``loader_times_s``) and a
    closing zero-polarity event at the last view's time (t.max())."""
    n = lead + len(t_views_us)
    bounds = check_increasing_bounds(loader_bounds_s(n, (n - 1) * step_s), where)
    t = loader_times_s(ev.t, t_views_us, bounds[lead:])
    return {"x": np.append(ev.x.astype(np.int16), np.int16(0)),
            "y": np.append(ev.y.astype(np.int16), np.int16(0)),
            "t": np.append(t, bounds[-1]),
            "p": np.append(signed_polarity(ev.p, where), np.int8(0))}


def _colour_events(src, fit: SensorFit) -> bool:
    """True for colour events EventNeRF's loader reads (RGGB, moved by an
    even offset); False for luminance events; InputError otherwise."""
    cfa = src.cfa
    if cfa is None:
        return False
    if cfa != "RGGB":
        raise InputError(f"{src.events_file}: events under a {cfa} filter; EventNeRF's colour loader "
                         "reads RGGB only (events.cfa: RGGB)")
    if fit.ox % 2 or fit.oy % 2:
        raise InputError(f"{src.events_file}: fitting {src.width}x{src.height} frames onto EventNeRF's "
                         f"sensor moves them by ({fit.ox}, {fit.oy}) px, which shifts the RGGB pattern "
                         "(render at 346x260: events.sensor color_davis346)")
    return True


def export_eventnerf(src, out: ExportOut, cfg: ExportSettings) -> None:
    t_frames = src.frames["t_us"].to_numpy()
    frames = src.covered_frames()
    fit = SensorFit.centred(src.width, src.height, SENSOR_W, SENSOR_H, cfg.eventnerf_fit,
                            "EventNeRF (data_loader_split.py)")
    colored = _colour_events(src, fit)
    c2w_all = src.c2w(frames)
    norm = unit_sphere(c2w_all[:, :3, 3], scene_points(src, frames))
    splits = split_frames(frames, int(cfg.eventnerf_holdout_every))
    if len(splits["validation"]) == len(frames):
        out.warn(f"{len(frames)} frames: too few to hold one out (EventNeRF validation and test are the "
                 "training frames)")
    winsize = choose_winsize(len(splits["train"]), cfg.eventnerf_winsize)
    step_s = (int(t_frames[frames[-1]]) - int(t_frames[frames[0]])) / (len(frames) - 1) * 1e-6
    info = {}
    for split, real in splits.items():
        lead = lead_in(split, winsize)
        views = np.concatenate([np.repeat(real[:1], lead), real])
        t0, t1 = int(t_frames[real[0]]), int(t_frames[real[-1]])
        ev, dropped = fit.events(src.events(t0, t1))
        for k, i in enumerate(views):
            name = f"{k:06d}"
            if 0 < k <= lead:  # views 0 .. lead are all the first frame: link view 0's files
                for sub, ext in (("pose", "txt"), ("intrinsics", "txt"), ("rgb", "png")):
                    out.same_as(f"{split}/{sub}/{name}.{ext}", f"{split}/{sub}/000000.{ext}")
                continue
            out.text(f"{split}/pose/{name}.txt", matrix_text(norm.apply_c2w(src.c2w([i])[0])))
            out.text(f"{split}/intrinsics/{name}.txt", matrix_text(intrinsics_matrix(fit.K(src.K(i)))))
            out.png(f"{split}/rgb/{name}.png", fit.image(src.image("rgb", i)))
        arrays = loader_events(ev, t_frames[real], lead, step_s, f"EventNeRF {split} split of {src.events_file}")
        np.savez(out.path(f"{split}/events/events.npz"), **arrays)
        if len(ev) == 0 and len(real) > 1:
            out.warn(f"{split}: no events in the exported span")
        first = 1 + (winsize if split == "train" else EVAL_MAX_WINSIZE)  # data_loader_split.py L86
        info[split] = {"gs2e_frames": views.tolist(), "lead_in": lead, "t0_us": t0, "t1_us": t1,
                       "n_events": len(ev), "events_dropped_off_sensor": dropped,
                       "loader_t_max_s": float(arrays["t"][-1]), "loader_views": views[first:].tolist()}
    place = (f"datadir = {out.final.parent}\nscene = {out.final.name}\n" if out.final
             else "# datadir = this folder's parent, scene = its name\n")
    out.text("eventnerf.txt",
             "# EventNeRF config keys for this export (add your experiment's keys)\n" + place +
             f"is_colored = {colored}\npolarity_offset = 0.0\nis_cycled = False\n"
             f"trainskip = 1\ntestskip = 1\nwinsize = {winsize}\n")
    out.manifest.update({
        "target": "r00tman/EventNeRF data_loader_split.py",
        "time": f"events.npz t: float64 seconds, view i of a split at i x {step_s:.9g} s (lead-in views "
                "first); each event rescaled linearly from its interval between two consecutive real views "
                "(absolute t0_us .. t1_us) onto the loader window [(j-1)/(N-1), j/(N-1)) x t.max()",
        "polarity": "events.npz p: int8, +1 ON, -1 OFF; the last event (p = 0, x = y = 0) sits at the "
                    "last view's time: it sets t.max() and is in no loader window",
        "winsize": winsize,
        "heldout_frames": [] if len(splits["validation"]) == len(frames) else splits["validation"].tolist(),
        "lead_in": "each split starts with lead_in copies of its first view (pose, intrinsics, image; hard "
                   "links): the loader's samplers start at view 1 + winsize (train) or 2 (validation, test)",
        "poses": "pose/*.txt: camera-to-world, OpenCV axes, after the normalisation",
        "normalisation": norm.to_dict(), "sensor_fit": fit.to_dict(), "splits": info,
    })
