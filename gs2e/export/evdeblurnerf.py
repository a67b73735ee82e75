"""EvDeblurNeRF (uzh-rpg/EvDeblurNeRF, ``data/loader.py`` LLFFDataset +
``data/loader_events.py`` LLFFEventsDataset) layout, read with factor = 1::

    <scene>/images_1/NNNNNN.png        blurred and sharp frames interleaved: sorted
                                       image k is a sharp test view when k % llffhold == 0
                                       (the loader's llffhold split), blurred otherwise
    <scene>/images_1/timestamps.npz    timestamps, timestamps_start, timestamps_end per
                                       image (us; start = end marks a sharp image; a
                                       blurred image's end is its exposure end - 0.5 us,
                                       float64), start, end (the events' span)
    <scene>/poses_bounds.npy           (N, 17) LLFF: 3x5 [down, right, back, centre,
                                       (H, W, focal)] + near, far per image
    <scene>/all_poses_bounds.npy       the same for dense poses (interpolation), with
    <scene>/all_timestamps.npy         their times (us)
    <scene>/events.h5                  datasets x, y, t (int64 us), p (0 OFF / 1 ON) at the root

Times are integer microseconds measured from ``time_origin_us`` = 1 s before
the first exported exposure (absolute gs2e time; the loader's EDI prior
asserts exposure starts > 0). With ``events_tms_unit = us`` the loader scales
them by 1 and keeps them integers (utils/events.py L32-37), so its event times
equal gs2e's. Train with ``factor = 1``, ``llffhold`` as exported,
``events_tms_unit = us``, ``events_tms_files_unit = us`` (``evdeblurnerf.txt``).
Its training batches are ``events_N_rand`` events that have a later event at
the same pixel, dropping an incomplete batch (run_nerf.py L86-90,
data/loader_events.py L255, L306-307): with fewer such events than its default
2048 the file sets ``events_N_rand`` to their count. The optional EDI prior
(``use_pts0_prior = edi``) sums a blurred image's events over the closed
[timestamps_start, timestamps_end] (searchsorted left at the start, right at
the end, data/loader_events.py L106-121); gs2e's exposure window is the
half-open [exp_t0_us, exp_t1_us), so ``timestamps_end`` is written as
exp_t1_us - 0.5 us (see ``image_timestamps``): the prior then sums exactly the
exposure's events. The loader builds
K from one focal with the principal point at the image centre (checked) and
asserts that the events hold both polarities (a warning names a one-sided
stream). Near/far bounds are the 0.1 / 99.9 % depth percentiles of each frame,
as LLFF derives them from COLMAP points.
"""

from __future__ import annotations

import numpy as np

from gs2e.common.errors import InputError
from gs2e.export.common import ExportOut, check_centred_square_pixels
from gs2e.export.conventions import check_polarity01
from gs2e.export.settings import ExportSettings

LEAD_US = 1_000_000  # time origin: this long before the first exposure start
EVENTS_N_RAND = 2048  # options.py: events_N_rand default 32 * 32 * 4 // 2
EDI_END_BEFORE_US = 0.5  # timestamps_end = exp_t1_us - this (see image_timestamps)


def image_timestamps(t_us: np.ndarray, ea: np.ndarray, eb: np.ndarray,
                     sharp: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``timestamps``, ``timestamps_start``, ``timestamps_end`` of
    images_1/timestamps.npz (us, on the events' axis) from the frame times and
    their integer exposures [ea, eb): a sharp image has start = end = its time.

    The EDI prior sums the events of the closed [start, end] (loader_events.py
    L106-121). A blurred image's end is eb - 0.5 us: on integer event times the
    closed window then holds exactly gs2e's [ea, eb). Its sub-interval
    boundaries start + j (end - start) / (steps - 1) = ea + j (2 (eb - ea) - 1)
    / (2 (steps - 1)) are never integers when steps - 1 is a power of 2
    (``pts0_edi_steps`` default 9), so no event lands on one and is summed into
    two sub-intervals."""
    t = np.asarray(t_us, np.int64)
    start = np.where(sharp, t, np.asarray(ea, np.int64))
    end = np.where(sharp, t.astype(np.float64), np.asarray(eb, np.int64) - EDI_END_BEFORE_US)
    return t, start, end


def n_with_successor(x: np.ndarray, y: np.ndarray, width: int) -> int:
    """Events followed by a later event at the same pixel (the loader's
    training samples): all events but each pixel's last."""
    return int(len(x) - len(np.unique(y.astype(np.int64) * width + x)))


def llff_rows(c2w: np.ndarray, height: int, width: int, focal: float, bounds: np.ndarray) -> np.ndarray:
    """(N, 17) poses_bounds rows: LLFF's [down, right, back] rotation columns
    (from OpenCV's right, down, forward), the centre, (H, W, focal), near, far."""
    n = len(c2w)
    m = np.zeros((n, 3, 5))
    m[:, :, 0] = c2w[:, :3, 1]
    m[:, :, 1] = c2w[:, :3, 0]
    m[:, :, 2] = -c2w[:, :3, 2]
    m[:, :, 3] = c2w[:, :3, 3]
    m[:, :, 4] = [height, width, focal]
    return np.concatenate([m.reshape(n, 15), np.asarray(bounds, np.float64).reshape(n, 2)], 1)


def export_evdeblurnerf(src, out: ExportOut, cfg: ExportSettings) -> None:
    import h5py

    w = src.windows
    frames = src.covered_frames()
    frames = frames[w["exp_covered"].to_numpy(bool)[frames]]
    if len(frames) < 2:
        raise InputError(f"{src.events_file}: fewer than 2 blurred frames have their exposure covered "
                         "by events (render.write_blur: false, or events too short)")
    K = src.K(int(frames[0]))
    check_centred_square_pixels(K, src.width, src.height, "EvDeblurNeRF (data/loader.py)")
    hold = int(cfg.evdeblurnerf_llffhold)
    t = src.frames["t_us"].to_numpy()
    ea = w["exp_t0_us"].to_numpy(np.int64)[frames]
    eb = w["exp_t1_us"].to_numpy(np.int64)[frames]
    sharp = np.arange(len(frames)) % hold == 0
    empty = np.flatnonzero(~sharp & (eb <= ea))
    if len(empty):
        raise InputError(f"{src.events_file}: the exposure of blurred frame {int(frames[empty[0]])} holds no "
                         "whole microsecond (render.exposure_us too short); EvDeblurNeRF needs start < end")
    origin = int(ea.min()) - LEAD_US
    ts, ts_start, ts_end = image_timestamps(t[frames] - origin, ea - origin, eb - origin, sharp)
    for k, i in enumerate(frames):
        out.png(f"images_1/{k:06d}.png", src.image("rgb" if sharp[k] else "blur", int(i)))
    span0, span1 = int(ea.min()), int(eb.max())
    np.savez(out.path("images_1/timestamps.npz"), timestamps=ts, timestamps_start=ts_start,
             timestamps_end=ts_end, start=np.int64(span0 - origin), end=np.int64(span1 - origin))
    bounds = src.depth_range(frames)
    focal = float(K[0, 0])
    np.save(out.path("poses_bounds.npy"), llff_rows(src.c2w(frames), src.height, src.width, focal, bounds))
    # dense poses for the loader's interpolation (Slerp + cubic translation)
    n_dense = max(4, int(np.ceil((span1 - span0) * 1e-6 * cfg.evdeblurnerf_pose_rate_hz)) + 1)
    t_dense = np.unique(np.concatenate([np.linspace(span0, span1, n_dense).round(), t[frames], ea, eb]))
    t_dense = t_dense[(t_dense >= span0) & (t_dense <= span1)].astype(np.int64)
    all_bounds = np.tile([bounds[:, 0].min(), bounds[:, 1].max()], (len(t_dense), 1))
    np.save(out.path("all_poses_bounds.npy"),
            llff_rows(src.poses_at(t_dense), src.height, src.width, focal, all_bounds))
    np.save(out.path("all_timestamps.npy"), t_dense - origin)
    ev = src.events(span0, span1)
    with h5py.File(out.path("events.h5"), "w") as f:
        comp = {"compression": "gzip", "compression_opts": 4, "shuffle": True} if len(ev) else {}
        f.create_dataset("x", data=ev.x.astype(np.uint16), **comp)
        f.create_dataset("y", data=ev.y.astype(np.uint16), **comp)
        f.create_dataset("t", data=(ev.t - origin).astype(np.int64), **comp)
        f.create_dataset("p", data=check_polarity01(ev.p, str(src.events_file)), **comp)
    if len(ev) == 0 or ev.p.min() == ev.p.max():
        out.warn("the events hold a single polarity (or none): the loader asserts both ON and OFF exist")
    n_samples = n_with_successor(ev.x, ev.y, src.width)
    if n_samples == 0:
        raise InputError(f"{src.events_file}: no pixel has two events in the exported span; EvDeblurNeRF "
                         "trains on pairs of consecutive events at a pixel")
    batch = ""
    if n_samples < EVENTS_N_RAND:
        out.warn(f"{n_samples} events have a successor at their pixel, fewer than EvDeblurNeRF's "
                 f"events_N_rand = {EVENTS_N_RAND}: evdeblurnerf.txt sets events_N_rand = {n_samples}")
        batch = f"events_N_rand = {n_samples}\n"
    out.text("evdeblurnerf.txt",
             f"# settings for EvDeblurNeRF's config (datadir = this folder)\ndataset_type = llff\n"
             f"factor = 1\nllffhold = {hold}\nevents_tms_unit = us\nevents_tms_files_unit = us\n" + batch)
    out.manifest.update({
        "target": "uzh-rpg/EvDeblurNeRF data/loader.py + data/loader_events.py",
        "time_origin_us": origin, "gs2e_frames": frames.tolist(), "sharp_images": np.nonzero(sharp)[0].tolist(),
        "time": "timestamps*.npz, all_timestamps.npy, events.h5 t: int64 us from time_origin_us "
                "(absolute gs2e time)",
        "edi_prior_window": "[timestamps_start, timestamps_end] (end included) with timestamps_end = "
                            "exp_t1_us - 0.5 us: exactly gs2e's events of [exp_t0_us, exp_t1_us)",
        "n_event_samples": n_samples,
        "polarity": "events.h5 p: 1 ON, 0 OFF (the loader maps 0 to -1)",
        "poses": "LLFF [down, right, back] columns of camera-to-world, gs2e world frame",
        "n_events": len(ev), "n_dense_poses": len(t_dense), "llffhold": hold,
    })
