"""Optical-flow ground truth of a trajectory (format ``flow``)::

    <out>/flow.h5                  every frame (Blosc-zstd like events.h5: import hdf5plugin)
        t_us (N,) int64                       frame times, absolute trajectory us
        forward_flow_px (N-1, H, W, 2) f4     frame i -> i+1: (dx, dy) px, +x right, +y down
        forward_valid (N-1, H, W) u1          1 = valid (see gs2e.groundtruth.flow)
        backward_flow_px (N-1, H, W, 2) f4    frame i+1 -> i, on frame i+1's pixels
        backward_valid (N-1, H, W) u1
        flow_px_per_s (N, H, W, 2) f4         instantaneous flow at the frame time
        flow_px_per_s_valid (N, H, W) u1      opaque pixels (alpha >= 0.5, gs2e.groundtruth.flow)
        depth_m (N, H, W) f4                  expected camera z in metres (NaN: not opaque)
    <out>/forward/NNNNNN.png       DSEC's 16-bit flow of frame NNNNNN -> the next
    <out>/backward/NNNNNN.png      ... of frame NNNNNN -> the previous (with flow_png)
    <out>/forward_timestamps.txt   DSEC's list: from_timestamp_us, to_timestamp_us
    <out>/backward_timestamps.txt
    <out>/event_flow.h5            with flow_per_event: per event of events.h5, in its order,
        flow_px_per_s (M, 2) f4, depth_m (M,) f4, valid (M,) u1, t_us (M,) i8

Flow comes from the rendered depth and the trajectory's exact poses
(displacement between frames) and velocities (instantaneous flow):
:mod:`gs2e.groundtruth.flow`. Per-event flow is the motion field at the
event's pixel and time with the trajectory's exact pose and velocity there
and the depth reprojected from the nearer of the two frames around the event
(:func:`gs2e.groundtruth.flow.depth_at_time`); it is valid where a frame
shows the surface the event's pixel sees at its time.
"""

from __future__ import annotations

import numpy as np

from gs2e.export.common import ExportOut
from gs2e.export.settings import ExportSettings
from gs2e.groundtruth.flow import (FlowSettings, depth_at_time, encode_dsec_png, flow_pair,
                                   motion_field, motion_field_at, surface_depth)

EVENT_CHUNK = 500_000


def _flow_png_params() -> list[int]:
    """zlib level 1 on the Sub filter: on the demo's flow PNGs 4.0 ms and 83 kB
    each, against 8.2 ms and 83 kB at gs2e's photo setting (level 3, Paeth)."""
    import cv2

    return [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]


def camera_velocities(src, t_us: np.ndarray):
    """(velocity_c (Q, 3) scene units/s, omega_c (Q, 3) rad/s): the camera's
    velocity and angular velocity in its own frame at times t_us."""
    from gs2e.trajectory.kinematics import kinematics_at

    k = kinematics_at(src.trajectory, np.asarray(t_us, np.float64))
    v_c = np.einsum("qji,qj->qi", k.c2w[:, :3, :3], k.velocity_w)
    return v_c, k.omega_c


def export_flow(src, out: ExportOut, cfg: ExportSettings) -> None:
    import h5py

    from gs2e.common.progress import progress
    from gs2e.events.io import h5_compression

    comp = h5_compression("blosc")
    st = FlowSettings()
    mpu = float(cfg.metres_per_unit)
    t = src.frames["t_us"].to_numpy().astype(np.int64)
    N, H, W = len(t), src.height, src.width
    v_c, w_c = camera_velocities(src, t)
    write_png = bool(cfg.flow_png)
    png_params = _flow_png_params()
    valid_frac, opaque_valid = [], []
    with h5py.File(out.path("flow.h5"), "w") as f:
        f.create_dataset("t_us", data=t)
        # (a trajectory of one frame has no frame pairs: empty datasets, unchunked)
        ds = {name: f.create_dataset(name, shape, dtype, **(dict(chunks=(1,) + shape[1:], **comp)
                                                           if shape[0] else {}))
              for name, shape, dtype in (
                  ("forward_flow_px", (max(N - 1, 0), H, W, 2), "f4"),
                  ("forward_valid", (max(N - 1, 0), H, W), "u1"),
                  ("backward_flow_px", (max(N - 1, 0), H, W, 2), "f4"),
                  ("backward_valid", (max(N - 1, 0), H, W), "u1"),
                  ("flow_px_per_s", (N, H, W, 2), "f4"),
                  ("flow_px_per_s_valid", (N, H, W), "u1"),
                  ("depth_m", (N, H, W), "f4"))}
        f.attrs.update({"width": W, "height": H, "metres_per_unit": mpu,
                        "alpha_min": st.alpha_min, "fb_rel": st.fb_rel, "fb_abs_px2": st.fb_abs_px2,
                        "conventions": "flow (dx, dy) in pixels, +x right, +y down; forward i -> i+1 "
                                       "on frame i's pixels, backward i+1 -> i on frame i+1's; "
                                       "flow_px_per_s: instantaneous, px per second; NaN: no flow"})
        prev = None
        for i in progress(range(N), desc=f"flow {src.traj}", total=N):
            d, a, c2w = src.depth(i), src.alpha(i), src.c2w([i])[0]
            K = src.K(i)
            z = surface_depth(d, a, st.alpha_min)
            inst = motion_field(z, K, v_c[i], w_c[i])
            ds["flow_px_per_s"][i] = inst
            ds["flow_px_per_s_valid"][i] = np.isfinite(z)
            ds["depth_m"][i] = z * mpu
            if prev is not None:
                pd, pa, pc2w = prev
                fp = flow_pair(pd, pa, d, a, K, pc2w, c2w, st)
                ds["forward_flow_px"][i - 1] = fp.forward
                ds["forward_valid"][i - 1] = fp.forward_valid
                ds["backward_flow_px"][i - 1] = fp.backward
                ds["backward_valid"][i - 1] = fp.backward_valid
                opaque = pa >= st.alpha_min
                valid_frac.append(float(fp.forward_valid.mean()))
                opaque_valid.append(float(fp.forward_valid[opaque].mean()) if opaque.any() else float("nan"))
                if write_png:
                    out.png(f"forward/{i - 1:06d}.png", encode_dsec_png(fp.forward, fp.forward_valid),
                            png_params)
                    out.png(f"backward/{i:06d}.png", encode_dsec_png(fp.backward, fp.backward_valid),
                            png_params)
            prev = (d, a, c2w)
    header = "# from_timestamp_us, to_timestamp_us\n"
    out.text("forward_timestamps.txt", header + "".join(f"{a}, {b}\n" for a, b in zip(t[:-1], t[1:])))
    out.text("backward_timestamps.txt", header + "".join(f"{b}, {a}\n" for a, b in zip(t[:-1], t[1:])))
    n_events = None
    if cfg.flow_per_event:
        n_events = _event_flow(src, out, st, mpu, t)
    out.manifest.update({
        "target": "optical flow, depth and per-event flow ground truth (DSEC PNG + HDF5)",
        "time": "t_us: absolute trajectory microseconds (events.h5 t + t_offset)",
        "flow": "pixels (displacement) or pixels per second (instantaneous); pixel centres at +0.5",
        "dsec_png": "16-bit RGB: R = dx * 128 + 2^15, G = dy * 128 + 2^15, B = valid" if write_png else None,
        "n_frames": int(N), "metres_per_unit": mpu,
        "forward_valid_fraction_median": float(np.median(valid_frac)) if valid_frac else None,
        "forward_valid_of_opaque_median": float(np.nanmedian(opaque_valid)) if opaque_valid else None,
        "n_events_with_flow": n_events})


def _event_flow(src, out: ExportOut, st: FlowSettings, mpu: float, t_frames: np.ndarray) -> int:
    """Per-event flow and depth into event_flow.h5 (module docstring); returns
    the event count."""
    import h5py

    from gs2e.events.io import h5_compression

    comp = h5_compression("blosc")
    ev = src.events()
    M = len(ev)
    K = src.K(0)
    depth_cache: dict[int, np.ndarray] = {}

    def z_of(i: int) -> np.ndarray:
        if i not in depth_cache:
            if len(depth_cache) > 4:
                depth_cache.pop(next(iter(depth_cache)))
            depth_cache[i] = surface_depth(src.depth(i), src.alpha(i), st.alpha_min)
        return depth_cache[i]

    with h5py.File(out.path("event_flow.h5"), "w") as f:
        c = comp if M else {}  # no events: empty datasets, unchunked
        d_flow = f.create_dataset("flow_px_per_s", (M, 2), "f4", **c)
        d_depth = f.create_dataset("depth_m", (M,), "f4", **c)
        d_valid = f.create_dataset("valid", (M,), "u1", **c)
        f.create_dataset("t_us", data=ev.t, **(comp if M else {}))
        f.attrs.update({"events_file": "events.h5", "n_events": M,
                        "conventions": "row k: the k-th event of events.h5; flow in px/s at the "
                                       "event's time and pixel centre; NaN where not valid"})
        for a in range(0, M, EVENT_CHUNK):
            b = min(M, a + EVENT_CHUNK)
            te = ev.t[a:b]
            x, y = ev.x[a:b].astype(np.int64), ev.y[a:b].astype(np.int64)
            # the frames around each event: t_frames[k] <= t < t_frames[k + 1]
            k = np.clip(np.searchsorted(t_frames, te, side="right") - 1, 0, len(t_frames) - 2)
            z = np.full(b - a, np.nan)
            poses = src.trajectory.pose_at(te.astype(np.float64))
            for i in (np.unique(k) if len(t_frames) > 1 else ()):  # one frame: no depth over time
                m = k == i
                w = (te[m] - t_frames[i]) / float(t_frames[i + 1] - t_frames[i])
                fa, fb = (src.c2w([int(i)])[0], z_of(int(i))), (src.c2w([int(i) + 1])[0], z_of(int(i) + 1))
                z[m] = depth_at_time(x[m] + 0.5, y[m] + 0.5, K, poses[m], w, fa, fb)
            v_c, w_c = camera_velocities(src, te)
            flow = motion_field_at(x + 0.5, y + 0.5, z, K, v_c, w_c)
            ok = np.isfinite(z)
            d_flow[a:b] = flow
            d_depth[a:b] = z * mpu
            d_valid[a:b] = ok
    return int(M)
