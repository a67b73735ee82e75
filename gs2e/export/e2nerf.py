"""E2NeRF (iCVTEAM/E2NeRF, ``load_blender.py`` + ``run_nerf_exp.py``) and
E2GS (deguchihiroyuki/E2GS, ``scene/dataset_readers.py``
readBlurNerfSyntheticInfo) synthetic layout::

    <scene>/transform_train.json  camera_angle_x; frames[2k] = training view k:
                                  file_path "./train/r_{2k}", transform_matrix = list
                                  of 18 camera-to-world 4x4 (NeRF/OpenGL axes); the
                                  loaders read entries 1, 5, 9, 13, 17 = 5 poses
                                  evenly over the exposure (start .. end); odd frame
                                  entries are skipped by both (gs2e repeats view k)
    <scene>/train/r_{2k}.png      the blurred frame of view k
    <scene>/transform_test.json   frames[2k] = frames[2k + 1] = test view k ("./test/r_{2k}",
                                  "./test/r_{2k+1}"), 18 copies of the pose of sharp
                                  frame k: E2GS reads frames[::2] (dataset_readers.py
                                  L272, L316), E2NeRF every entry with the image
                                  ./test/r_{j}.png (load_blender.py L60-64), so each
                                  view is tested once by E2GS, twice by E2NeRF (same mean)
    <scene>/test/r_{j}.png        the sharp frame of test view j // 2
    <scene>/events.pt             torch float32 (views, 4, H, W): bin b = ON minus OFF
                                  count between exposure poses b and b + 1
    <scene>/sparse/0/             COLMAP model with the SfM points (E2GS reads
                                  points3D.bin; same world frame as the poses); its
                                  images are named r_{2k}.png
    <scene>/images/r_{2k}.png     the blurred frame of view k again (hard link), E2GS's
                                  README layout: the COLMAP model's images. E2GS's
                                  render_novel.py takes the size of every novel view from
                                  images/r_0.png (dataset_readers.py L505-507, L515) and
                                  its poses from transform_test.json frames[1::2] (L491)

Both derive intrinsics from ``camera_angle_x`` with fx = fy and the principal
point at the image centre (checked). E2GS reads any image size and view
count; E2NeRF's run_nerf_exp.py hard-codes 800x800 pixels, 100 views and
near/far = 2/6: with ``e2nerf_loader: e2nerf`` the export checks the size,
takes 100 evenly spaced views and scales the world so the frames' depth range
falls inside [2, 6] (an error names what does not fit).
"""

from __future__ import annotations

import json

import numpy as np

from gs2e.common.errors import InputError
from gs2e.events.represent import event_frame
from gs2e.export.common import ExportOut, Similarity, angle_x, check_centred_square_pixels
from gs2e.export.settings import ExportSettings
from gs2e.io.scene import opencv_to_opengl

N_SUBPOSES = 18          # the loaders index transform_matrix[1 + 4 j], j = 0..4
N_BINS = 4               # event bins between the 5 exposure poses
E2NERF_SIZE = (800, 800)  # run_nerf_exp.py: resolution_h, resolution_w = 800, 800
E2NERF_VIEWS = 100        # run_nerf_exp.py: view_num = 100
E2NERF_NEAR, E2NERF_FAR = 2.0, 6.0


def subpose_times_us(ea: float, eb: float) -> np.ndarray:
    """Times of the 18 transform_matrix entries: entry m at ea + (m - 1)(eb - ea)/16,
    so entries 1, 5, 9, 13, 17 are the exposure's start, quarters and end."""
    return ea + (np.arange(N_SUBPOSES) - 1) * (eb - ea) / (N_SUBPOSES - 2)


def bin_edges_us(ea: int, eb: int) -> np.ndarray:
    """Integer edges of the 4 event bins of an exposure [ea, eb) (ceilings of
    the exact quarter times, like the windows table)."""
    return np.ceil(ea + np.arange(N_BINS + 1) * (eb - ea) / N_BINS).astype(np.int64)


def export_e2nerf(src, out: ExportOut, cfg: ExportSettings) -> None:
    import torch

    strict = cfg.e2nerf_loader == "e2nerf"
    w = src.windows
    frames = src.covered_frames()
    frames = frames[w["exp_covered"].to_numpy(bool)[frames]]
    if len(frames) == 0:
        raise InputError(f"{src.events_file}: no blurred frame has its exposure covered by events "
                         "(render.write_blur: false, or events too short)")
    K = src.K(int(frames[0]))
    check_centred_square_pixels(K, src.width, src.height, "E2NeRF/E2GS")
    norm = Similarity(np.zeros(3), 1.0)
    if strict:
        if (src.width, src.height) != E2NERF_SIZE:
            raise InputError(f"E2NeRF (run_nerf_exp.py) hard-codes 800x800 frames; these are "
                             f"{src.width}x{src.height} (use e2nerf_loader: e2gs, or render at 800x800)")
        if len(frames) < E2NERF_VIEWS:
            raise InputError(f"E2NeRF (run_nerf_exp.py) hard-codes 100 views; the events cover "
                             f"{len(frames)} blurred frames")
        frames = frames[np.linspace(0, len(frames) - 1, E2NERF_VIEWS).round().astype(int)]
        d = src.depth_range(frames)
        lo, hi = float(d[:, 0].min()), float(d[:, 1].max())
        if hi / lo > E2NERF_FAR / E2NERF_NEAR:
            raise InputError(f"E2NeRF samples depths 2..6 only; the frames' depths span {lo:.3g}..{hi:.3g} "
                             f"(ratio {hi / lo:.1f} > 3): no scale fits")
        norm = Similarity(np.zeros(3), float(np.sqrt(E2NERF_NEAR * E2NERF_FAR / (lo * hi))))
    t = src.frames["t_us"].to_numpy()
    shape = (src.height, src.width)
    train, test = [], []
    bins = np.zeros((len(frames), N_BINS, src.height, src.width), np.float32)
    n_events = 0
    for k, i in enumerate(frames):
        ea, eb = int(w["exp_t0_us"].iloc[i]), int(w["exp_t1_us"].iloc[i])
        ts = np.clip(subpose_times_us(ea, eb), t[0], t[-1])
        mats = opencv_to_opengl(norm.apply_c2w(src.poses_at(ts)))
        entry = {"file_path": f"./train/r_{2 * k}", "transform_matrix": mats.tolist(),
                 "gs2e_frame": int(i), "exposure_us": [ea, eb]}
        train += [entry, dict(entry)]
        out.png(f"train/r_{2 * k}.png", src.image("blur", int(i)))
        out.same_as(f"images/r_{2 * k}.png", f"train/r_{2 * k}.png")  # E2GS README; render_novel.py
        ev = src.events(ea, eb)
        n_events += len(ev)
        edges = bin_edges_us(ea, eb)
        for b in range(N_BINS):
            bins[k, b] = event_frame(ev, shape, int(edges[b]), int(edges[b + 1]), mode="signed")
        sharp = opencv_to_opengl(norm.apply_c2w(src.c2w([i])[0]))
        rgb = src.image("rgb", int(i))
        for j in (2 * k, 2 * k + 1):  # E2GS keeps frames[::2]; E2NeRF reads all (see module docstring)
            test.append({"file_path": f"./test/r_{j}", "transform_matrix": [sharp.tolist()] * N_SUBPOSES,
                         "gs2e_frame": int(i), "t_us": int(t[i])})
            out.png(f"test/r_{j}.png", rgb)
    fov = angle_x(K, src.width)
    out.text("transform_train.json", json.dumps({"camera_angle_x": fov, "frames": train}, indent=1))
    out.text("transform_test.json", json.dumps({"camera_angle_x": fov, "frames": test}, indent=1))
    torch.save(torch.from_numpy(bins), out.path("events.pt"))
    _write_points(src, out, frames, norm)
    if not strict and ((src.width, src.height) != E2NERF_SIZE or len(frames) != E2NERF_VIEWS):
        out.warn(f"{src.width}x{src.height}, {len(frames)} views: readable by E2GS; E2NeRF's "
                 "run_nerf_exp.py hard-codes 800x800 and 100 views (e2nerf_loader: e2nerf checks them)")
    out.manifest.update({
        "target": "iCVTEAM/E2NeRF load_blender.py + run_nerf_exp.py; deguchihiroyuki/E2GS "
                  "readBlurNerfSyntheticInfo",
        "loader": cfg.e2nerf_loader, "gs2e_frames": frames.tolist(), "n_events": n_events,
        "test_views": "transform_test.json frames[2k] and frames[2k + 1] are gs2e_frames[k]",
        "images": "images/r_{2k}.png = train/r_{2k}.png (the COLMAP model's image names; E2GS's "
                  "render_novel.py reads the frame size from images/r_0.png)",
        "time": "exposure bins: [exp_t0_us, exp_t1_us) of the windows table, split in 4 equal parts",
        "polarity": "events.pt: ON count minus OFF count per bin",
        "poses": "transform_*.json: camera-to-world, NeRF/OpenGL axes (y up, z backward)",
        "normalisation": norm.to_dict(),
    })


def _write_points(src, out: ExportOut, frames: np.ndarray, norm: Similarity) -> None:
    """sparse/0 COLMAP model: the views' sharp poses and the SfM points (E2GS)."""
    from gs2e.io.colmap import write_colmap_model
    from gs2e.io.scene import Camera, Frame, Scene

    xyz, rgb = src.points()
    K = src.K(int(frames[0]))
    cam = Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2])
    views = [Frame(f"r_{2 * k}.png", cam, norm.apply_c2w(src.c2w([i])[0])) for k, i in enumerate(frames)]
    if not len(xyz):
        out.warn("no SfM points: sparse/0/points3D.bin is empty (E2GS needs an initial point cloud)")
    write_colmap_model(Scene(src.width, src.height, views, "e2nerf",
                             points_xyz=norm.apply_points(xyz) if len(xyz) else None,
                             points_rgb=rgb if len(xyz) else None), out.path("sparse/0"))
