"""IncEventGS (WU-CVGL/IncEventGS, ``datasets/dataset.py``, dataset
``replica_simu_event``) layout::

    <scene>/images/frameNNNNNN.jpg                  one image per pose (sorted glob *.jpg)
    <scene>/traj.txt                                one row per image: 16 floats, the 4x4
                                                    camera-to-world, row-major, OpenCV axes
    <scene>/poses_ts.txt                            one time per image (float seconds)
    <scene>/event_threshold_0.1/gray_events_data.npy (M, 4) float64 [x, y, t, p]:
                                                    t in seconds (same origin as poses_ts),
                                                    p = -1 OFF / +1 ON (summed into event maps)
    <scene>/gs2e_inceventgs.yaml                    the cam: and data: keys of its config

The loader reads poses_ts.txt as float64 (np.loadtxt), casts the events to
float32 (datasets/dataset.py L382) and takes image i's events with
``poses_ts[i-1] <= t < poses_ts[i]`` (L133-139, L458): a float32 array against
a float64 scalar, compared in float32 by NumPy 1 and in float64 by NumPy 2.
gs2e writes every time as a float32 value (seconds from the first exported
frame; poses_ts.txt with enough digits to read back exactly), each event
clipped into its window's bounds, so both comparisons select exactly gs2e's
windows. Past 8 s a float32 second is coarser than 0.5 us, so event times
move by up to one float32 step (a warning gives the resolution).
Intrinsics come from the YAML config, written exactly: its renderer uses them
as they are (ReplicaEventDataset.K, L363-369). Its BaseDataset also floors
them (``cam.fx // downsample``, L112-115) for the rays of its depth-based
initialisation, densification and warping (datasets/utils.py get_camera_rays
L31-52; main.py L685-688, L817-820, L2798-2801). The export cannot make them
integers: the focal length is the renderer's, and resampling the images would
move them off the event sensor's pixel grid (cropping moves cx, cy by whole
pixels only). For non-integer intrinsics a warning and the manifest's
``intrinsics_floor_error_px`` give how far those rays miss their pixel
(``floored_ray_error_px``); IncEventGS's own Replica configs floor too
(fx = 548.409).
"""

from __future__ import annotations

import cv2
import numpy as np

from gs2e.export.common import ExportOut, check_increasing_bounds, times_in_loader_windows
from gs2e.export.conventions import signed_polarity
from gs2e.export.settings import ExportSettings

FLOAT32_FINE_US = 8_000_000  # float32 seconds have steps <= 0.5 us below 8 s


def pose_times_s(t_frames_us: np.ndarray) -> np.ndarray:
    """float32 seconds of the frames from the first one (the loader's time axis)."""
    t = np.asarray(t_frames_us, np.int64)
    return ((t - t[0]) * 1e-6).astype(np.float32)


def floored_ray_error_px(K: np.ndarray, width: int, height: int) -> float:
    """Largest distance (pixels) between a pixel and where IncEventGS's ray for
    it meets the image under the exact intrinsics: the ray of pixel (i, j) is
    ((i - cx) / fx, (j - cy) / fy, 1) with floored fx, fy, cx, cy (see module
    docstring), the renderer projects with the exact ones. 0 for integers."""
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    i, j = np.array([0.0, width - 1.0]), np.array([0.0, height - 1.0])  # the error is affine in i, j
    ex = fx * (i - np.floor(cx)) / np.floor(fx) + cx - i
    ey = fy * (j - np.floor(cy)) / np.floor(fy) + cy - j
    return float(np.hypot(np.abs(ex).max(), np.abs(ey).max()))


def export_inceventgs(src, out: ExportOut, cfg: ExportSettings) -> None:
    frames = src.covered_frames()
    t_frames = src.frames["t_us"].to_numpy()[frames]
    t0, t1 = int(t_frames[0]), int(t_frames[-1])
    names = []
    for i in frames:
        name = f"frame{int(i):06d}.jpg"
        ok, buf = cv2.imencode(".jpg", src.image("rgb", int(i))[:, :, ::-1],
                               [cv2.IMWRITE_JPEG_QUALITY, int(cfg.inceventgs_jpeg_quality)])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        out.path(f"images/{name}").write_bytes(buf.tobytes())
        names.append(name)
    c2w = src.c2w(frames)
    np.savetxt(out.path("traj.txt"), c2w.reshape(len(frames), 16), fmt="%.17g")
    poses_ts = check_increasing_bounds(pose_times_s(t_frames), f"IncEventGS poses_ts of {src.events_file}")
    # shortest float64 repr of each float32 value: np.loadtxt reads it back exactly
    out.text("poses_ts.txt", "".join(f"{float(v)!r}\n" for v in poses_ts))
    ev = src.events(t0, t1)
    arr = np.stack([ev.x.astype(np.float64), ev.y.astype(np.float64),
                    times_in_loader_windows(ev.t, t_frames, poses_ts).astype(np.float64),
                    signed_polarity(ev.p, str(src.events_file)).astype(np.float64)], 1)
    np.save(out.path("event_threshold_0.1/gray_events_data.npy"), arr.reshape(-1, 4))
    K = src.K(int(frames[0]))
    if t1 - t0 > FLOAT32_FINE_US:
        step_us = float(np.spacing(np.float32((t1 - t0) * 1e-6))) * 1e6
        out.warn(f"sequence is {(t1 - t0) / 1e6:.1f} s long: the loader's float32 seconds resolve "
                 f"{step_us:.2f} us at its end (event times rounded to that; windows stay exact)")
    floor_err = floored_ray_error_px(K, src.width, src.height)
    if floor_err > 0:
        vals = ", ".join(f"{float(v):.6g} -> {np.floor(v):.0f}" for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        out.warn(f"non-integer intrinsics: IncEventGS floors fx, fy, cx, cy ({vals}; datasets/dataset.py "
                 f"L112-115) for the rays of its depth initialisation, densification and warping, which then "
                 f"miss their pixel by up to {floor_err:.3f} px (its renderer uses the exact values)")
    yaml_text = (
        "# IncEventGS config for this export: inherit a Replica config for the method's settings\n"
        "inherit_from: configs/SimuEvent/replica_room0.yaml\n"
        "dataset: replica_simu_event\n"
        "evaluate_img: False\n"
        "data:\n"
        f"  datadir: {out.final or '.'}\n"
        "  training_start_index: 0\n"
        f"  training_end_index: {len(frames)}\n"
        "  interval_selection: 1\n"
        "cam:\n"
        f"  H: {src.height}\n  W: {src.width}\n"
        # Python floats: numpy 2 writes np.float64(...) as its repr
        f"  fx: {float(K[0, 0])!r}\n  fy: {float(K[1, 1])!r}\n"
        f"  cx: {float(K[0, 2])!r}\n  cy: {float(K[1, 2])!r}\n"
        "  crop_edge: 0\n")
    out.text("gs2e_inceventgs.yaml", yaml_text)
    out.manifest.update({
        "target": "WU-CVGL/IncEventGS datasets/dataset.py ReplicaEventDataset",
        "time": f"poses_ts.txt and events t: float32-exact seconds from the first exported frame "
                f"(absolute t0_us = {t0}), each event inside its window [poses_ts[i-1], poses_ts[i])",
        "polarity": "gray_events_data.npy p: +1 ON, -1 OFF",
        "poses": "traj.txt: camera-to-world (row-major 16 floats), OpenCV axes, gs2e world frame",
        "gs2e_frames": frames.tolist(), "t0_us": t0, "t1_us": t1, "n_events": len(ev),
        "intrinsics_floor_error_px": floor_err,
        "images": names,
    })
