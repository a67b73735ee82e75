"""EvDeblurNeRF (uzh-rpg/EvDeblurNeRF, ``data/loader.py`` LLFFDataset +
``data/loader_events.py`` LLFFEventsDataset) layout, read with factor = 1::

    <scene>/images_1/NNNNNN.png        blurred and sharp frames interleaved: sorted
                                       image k is a sharp test view when k % llffhold == 0
                                       (the loader's llffhold split), blurred otherwise
    <scene>/images_1/timestamps.npz    timestamps, timestamps_start, timestamps_end per
                                       image (us; start = end marks a sharp image),
                                       start, end (the events' span)
    <scene>/poses_bounds.npy           (N, 17) LLFF: 3x5 [down, right, back, centre,
                                       (H, W, focal)] + near, far per image
    <scene>/all_poses_bounds.npy       the same for dense poses (interpolation), with
    <scene>/all_timestamps.npy         their times (us)
    <scene>/events.h5                  datasets x, y, t (ns), p (0 OFF / 1 ON) at the root

Times are microseconds (files) and nanoseconds (events.h5) measured from
``time_origin_us`` = 1 s before the first exported exposure (absolute gs2e
time; the loader's EDI prior asserts exposure starts > 0). Train with
``factor = 1``, ``llffhold`` as exported, ``events_tms_unit = ns``,
``events_tms_files_unit = us`` (``evdeblurnerf.txt``). The loader builds
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

LEAD_US = 1_000_000  # time origin: this long before the first exposure start


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


def export_evdeblurnerf(src, out: ExportOut, cfg: dict) -> None:
    import h5py

    w = src.windows
    frames = src.covered_frames()
    frames = frames[w["exp_covered"].to_numpy(bool)[frames]]
    if len(frames) < 2:
        raise InputError(f"{src.events_file}: fewer than 2 blurred frames have their exposure covered "
                         "by events (render.write_blur: false, or events too short)")
    K = src.K(int(frames[0]))
    check_centred_square_pixels(K, src.width, src.height, "EvDeblurNeRF (data/loader.py)")
    hold = int(cfg["evdeblurnerf_llffhold"])
    t = src.frames["t_us"].to_numpy()
    ea = w["exp_t0_us"].to_numpy(np.int64)[frames]
    eb = w["exp_t1_us"].to_numpy(np.int64)[frames]
    sharp = np.arange(len(frames)) % hold == 0
    origin = int(ea.min()) - LEAD_US
    ts = t[frames] - origin
    ts_start = np.where(sharp, ts, ea - origin)
    ts_end = np.where(sharp, ts, eb - origin)
    for k, i in enumerate(frames):
        out.png(f"images_1/{k:06d}.png", src.image("rgb" if sharp[k] else "blur", int(i)))
    span0, span1 = int(ea.min()), int(eb.max())
    np.savez(out.path("images_1/timestamps.npz"), timestamps=ts, timestamps_start=ts_start,
             timestamps_end=ts_end, start=np.int64(span0 - origin), end=np.int64(span1 - origin))
    bounds = src.depth_range(frames)
    focal = float(K[0, 0])
    np.save(out.path("poses_bounds.npy"), llff_rows(src.c2w(frames), src.height, src.width, focal, bounds))
    # dense poses for the loader's interpolation (Slerp + cubic translation)
    n_dense = max(4, int(np.ceil((span1 - span0) * 1e-6 * cfg["evdeblurnerf_pose_rate_hz"])) + 1)
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
        f.create_dataset("t", data=(ev.t - origin) * 1000, **comp)
        f.create_dataset("p", data=check_polarity01(ev.p, str(src.events_file)), **comp)
    if len(ev) == 0 or ev.p.min() == ev.p.max():
        out.warn("the events hold a single polarity (or none): the loader asserts both ON and OFF exist")
    out.text("evdeblurnerf.txt",
             f"# settings for EvDeblurNeRF's config (datadir = this folder)\ndataset_type = llff\n"
             f"factor = 1\nllffhold = {hold}\nevents_tms_unit = ns\nevents_tms_files_unit = us\n")
    out.manifest.update({
        "target": "uzh-rpg/EvDeblurNeRF data/loader.py + data/loader_events.py",
        "time_origin_us": origin, "gs2e_frames": frames.tolist(), "sharp_images": np.nonzero(sharp)[0].tolist(),
        "time": "timestamps*.npz, all_timestamps.npy: int64 us; events.h5 t: int64 ns; both from "
                "time_origin_us (absolute gs2e time)",
        "polarity": "events.h5 p: 1 ON, 0 OFF (the loader maps 0 to -1)",
        "poses": "LLFF [down, right, back] columns of camera-to-world, gs2e world frame",
        "n_events": len(ev), "n_dense_poses": len(t_dense), "llffhold": hold,
    })
