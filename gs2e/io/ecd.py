"""Event Camera Dataset (ECD) sequences as a scene with given cameras and poses.

An ECD sequence folder (Mueller et al., IJRR 2017; e.g. ``../shared/data/slider_depth``)
holds::

    images.txt        t_s path           one APS frame per line
    groundtruth.txt   t_s x y z qx qy qz qw   camera-to-world (metres; Hamilton, scalar last)
    calib.txt         fx fy cx cy k1 k2 p1 p2 k3   (radial-tangential, pixels)
    events.txt        t_s x y p          (read by gs2e.events.recordings)

Each APS frame becomes a view with the calibrated camera (COLMAP ``OPENCV``,
or ``FULL_OPENCV`` when k3 != 0; structure from motion undistorts it) and the
pose interpolated at the frame's time (linear centre, slerp rotation). Frames
outside the ground truth's time span have no pose and are left out (listed in
the provenance). The camera axes of the ECD ground truth are OpenCV's
(+x right, +y down, +z forward), gs2e's own.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from gs2e.common.errors import InputError
from gs2e.io.scene import Camera
from gs2e.io.views import SourceView

FILES = ("images.txt", "groundtruth.txt", "calib.txt")


def _rows(path: Path, ncols: int, what: str) -> np.ndarray:
    if not path.is_file():
        raise InputError(f"{path} does not exist (an ECD sequence folder has {', '.join(FILES)})")
    try:
        a = np.loadtxt(path, ndmin=2, comments="#")
    except ValueError as exc:
        raise InputError(f"{path}: not a table of numbers ({exc})") from None
    if a.shape[1] != ncols or not len(a) or not np.all(np.isfinite(a)):
        raise InputError(f"{path}: expected finite rows '{what}', got shape {a.shape}")
    return a


def read_calib(path: str | Path) -> Camera:
    """The calibrated camera of ``calib.txt`` (``fx fy cx cy k1 k2 p1 p2 k3``).

    ECD's pixel coordinates put the centre of the top-left pixel at (0, 0)
    (OpenCV); gs2e's at (0.5, 0.5), so cx and cy move by half a pixel."""
    path = Path(path)
    c = _rows(path, 9, "fx fy cx cy k1 k2 p1 p2 k3")[0]
    fx, fy, cx, cy, k1, k2, p1, p2, k3 = (float(v) for v in c)
    if k3 == 0.0:
        return Camera(fx, fy, cx + 0.5, cy + 0.5, "OPENCV", [k1, k2, p1, p2])
    return Camera(fx, fy, cx + 0.5, cy + 0.5, "FULL_OPENCV", [k1, k2, p1, p2, k3, 0.0, 0.0, 0.0])


def read_groundtruth(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(t_s (N,), c2w (N, 4, 4)) of ``groundtruth.txt``; times strictly increasing."""
    path = Path(path)
    g = _rows(path, 8, "t_s x y z qx qy qz qw")
    if np.any(np.diff(g[:, 0]) <= 0):
        raise InputError(f"{path}: times are not strictly increasing")
    norms = np.linalg.norm(g[:, 4:], axis=1)
    if np.any(np.abs(norms - 1) > 1e-3):
        i = int(np.argmax(np.abs(norms - 1)))
        raise InputError(f"{path}: row {i + 1} has a quaternion of norm {norms[i]:.4g}, not 1")
    c2w = np.tile(np.eye(4), (len(g), 1, 1))
    c2w[:, :3, :3] = Rotation.from_quat(g[:, 4:]).as_matrix()  # scalar last, as ECD
    c2w[:, :3, 3] = g[:, 1:4]
    return g[:, 0].copy(), c2w


def poses_at(t_gt_s: np.ndarray, c2w_gt: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Poses (M, 4, 4) at times ``t_s`` (M,) inside the ground truth's span:
    centres linear, rotations slerped between the neighbouring samples."""
    t_s = np.asarray(t_s, np.float64)
    if t_s.size and (t_s.min() < t_gt_s[0] or t_s.max() > t_gt_s[-1]):
        raise ValueError(f"times outside the ground truth's span [{t_gt_s[0]}, {t_gt_s[-1]}] s")
    out = np.tile(np.eye(4), (len(t_s), 1, 1))
    out[:, :3, 3] = np.stack([np.interp(t_s, t_gt_s, c2w_gt[:, i, 3]) for i in range(3)], axis=1)
    if len(t_gt_s) == 1:
        out[:, :3, :3] = c2w_gt[0, :3, :3]
    else:
        out[:, :3, :3] = Slerp(t_gt_s, Rotation.from_matrix(c2w_gt[:, :3, :3]))(t_s).as_matrix()
    return out


def read_ecd_views(src: str | Path) -> tuple[list[SourceView], dict]:
    """The views of an ECD sequence folder (frames with a pose) and the provenance."""
    src = Path(src)
    if not src.is_dir():
        raise InputError(f"ECD sequence folder {src} is not a directory")
    cam = read_calib(src / "calib.txt")
    t_gt, c2w_gt = read_groundtruth(src / "groundtruth.txt")
    path = src / "images.txt"
    if not path.is_file():
        raise InputError(f"{path} does not exist (an ECD sequence folder has {', '.join(FILES)})")
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    bad = [i for i, r in enumerate(rows) if len(r) != 2]
    if bad or not rows:
        raise InputError(f"{path}: expected lines 't_s path'" + (f" (line {bad[0] + 1})" if bad else ""))
    try:
        t_img = np.array([float(r[0]) for r in rows])
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    inside = (t_img >= t_gt[0]) & (t_img <= t_gt[-1])
    poses = poses_at(t_gt, c2w_gt, t_img[inside])
    views = [SourceView(r[1], src / r[1], cam, None, c2w)
             for r, c2w in zip((r for r, k in zip(rows, inside) if k), poses)]
    prov = {"ecd_folder": str(src), "camera_time_s": [float(t) for t in t_img[inside]],
            "frames_without_pose": [r[1] for r, k in zip(rows, inside) if not k],
            "groundtruth_span_s": [float(t_gt[0]), float(t_gt[-1])]}
    return views, prov
