"""Scenes that come with their own cameras in the two layouts researchers'
captures often ship besides COLMAP and transforms.json:

- **LLFF** (``poses_bounds.npy``, Mildenhall et al., "Local Light Field
  Fusion", SIGGRAPH 2019; what the NeRF codebases and EvDeblurNeRF read): one
  row of 17 floats per image, the images in plain string order of their names
  (LLFF's ``sorted``: ``10.jpg`` before ``2.jpg``): a 3x5 matrix
  [down, right, back | centre | (H, W, focal)] flattened row by row, then the
  near and far bounds. The rotation columns are the camera's axes in LLFF's
  [down, right, backwards] order (LLFF's ``imgs2poses`` builds them from
  COLMAP's [right, down, forward]); the principal point is the image centre.
  gs2e's own EvDeblurNeRF export writes the same rows
  (:func:`gs2e.export.evdeblurnerf.llff_rows`).
- **Projection matrices**, one 3x4 P = K [R | t] (world to image, OpenCV
  axes) per image: AliceVision / openMVS's ``cameras_P/<id>_P.txt`` beside
  an ``mvs.ini`` that gives the size they are for (``width`` / ``scale``,
  ``height`` / ``scale``), or a Middlebury ``*_par.txt`` (one line per image:
  ``name k11..k33 r11..r33 t1 t2 t3``, for the images as stored). P is split
  into K, R and t by an RQ decomposition (OpenCV's
  ``decomposeProjectionMatrix``).
"""

from __future__ import annotations

import configparser
from pathlib import Path

import numpy as np

from gs2e.common.errors import InputError
from gs2e.io.images import image_size, list_images
from gs2e.io.scene import Camera, check_pose
from gs2e.io.views import SourceView, natural_key

POSES_BOUNDS = "poses_bounds.npy"


def llff_c2w(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(c2w (N, 4, 4) OpenCV axes, hwf (N, 3)) of poses_bounds rows (N, 17)."""
    m = np.asarray(rows, np.float64)[:, :15].reshape(-1, 3, 5)
    c2w = np.zeros((len(m), 4, 4))
    c2w[:, :3, 0] = m[:, :, 1]   # right
    c2w[:, :3, 1] = m[:, :, 0]   # down
    c2w[:, :3, 2] = -m[:, :, 2]  # forward = -back
    c2w[:, :3, 3] = m[:, :, 3]
    c2w[:, 3, 3] = 1.0
    return c2w, m[:, :, 4]


def _image_dir(src: Path) -> Path:
    folder = src / "images" if (src / "images").is_dir() else src
    if not list_images(folder):
        raise InputError(f"no images in {folder}")
    return folder


def read_llff_views(src: Path) -> tuple[list[SourceView], dict]:
    """Views of an LLFF capture: ``src/poses_bounds.npy`` and ``src/images/``
    (or the images beside it), row k for the k-th image in plain string order
    (checked on tumbler_cup_desk, which ships both: the rows equal its COLMAP
    model's poses there, not in natural order). The
    bounds are returned in the provenance. InputError naming the file for a
    malformed array, a count that differs from the images, or a row whose
    rotation is not one."""
    path = src / POSES_BOUNDS
    try:
        rows = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable LLFF poses_bounds array ({exc})") from exc
    if rows.ndim != 2 or rows.shape[1] != 17 or not np.all(np.isfinite(rows)):
        raise InputError(f"{path}: expected (N, 17) finite LLFF rows, got {rows.shape}")
    files = sorted(list_images(_image_dir(src)), key=lambda p: p.name)
    if len(files) != len(rows):
        raise InputError(f"{path}: {len(rows)} rows for {len(files)} images in {_image_dir(src)} "
                         "(LLFF pairs the k-th row with the k-th image by name)")
    c2w, hwf = llff_c2w(rows)
    views = []
    for k, (p, T, (h, w, f)) in enumerate(zip(files, c2w, hwf)):
        if not (h > 0 and w > 0 and f > 0):
            raise InputError(f"{path}: row {k} ({p.name}) has height/width/focal {h}, {w}, {f}")
        T = check_pose(T, f"{path}: row {k} ({p.name})")
        views.append(SourceView(p.name, p, Camera(float(f), float(f), w / 2.0, h / 2.0), (int(round(w)),
                                int(round(h))), T))
    bounds = rows[:, 15:17]
    return views, {"poses": str(path), "near_far": [float(bounds[:, 0].min()), float(bounds[:, 1].max())]}


def decompose_projection(P: np.ndarray, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3) with a positive diagonal, c2w (4, 4)) of a 3x4 projection
    matrix P = K [R | t] (OpenCV axes, P up to scale)."""
    import cv2

    P = np.asarray(P, np.float64)
    if P.shape != (3, 4) or not np.all(np.isfinite(P)) or abs(np.linalg.det(P[:, :3])) < 1e-12:
        raise InputError(f"{where}: not a finite 3x4 projection matrix of rank 3")
    K, R, C = cv2.decomposeProjectionMatrix(P)[:3]
    K = K / K[2, 2]
    # cv2 may return a negative focal length with R flipped to match: make K's diagonal positive
    S = np.diag(np.sign(np.diag(K)))
    K, R = K @ S, S @ R
    if np.linalg.det(R) < 0:  # P was given up to a negative scale
        R = -R
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = (C[:3] / C[3]).ravel()
    return K, check_pose(c2w, where)


def _camera(K: np.ndarray) -> Camera:
    return Camera(float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]))


def read_projection_views(src: Path) -> tuple[list[SourceView], dict]:
    """Views of a capture with one projection matrix per image (module
    docstring): ``cameras_P/`` + ``mvs.ini`` (AliceVision) or a ``*_par.txt``
    (Middlebury). Pixel centres: OpenCV's P counts the top-left pixel's
    centre as (0, 0), gs2e as (0.5, 0.5), so cx, cy move by half a pixel."""
    images = sorted(list_images(_image_dir(src)), key=lambda p: natural_key(p.name))
    pars = sorted(src.glob("*_par.txt"))
    views = []
    if (src / "cameras_P").is_dir():
        size = _mvs_size(src / "mvs.ini")
        for p in images:
            f = src / "cameras_P" / f"{p.name.split('.')[0]}_P.txt"
            if not f.is_file():
                raise InputError(f"{f} does not exist (the projection matrix of {p})")
            try:
                P = np.loadtxt(f)
            except ValueError as exc:
                raise InputError(f"{f}: not a 3x4 matrix of numbers ({exc})") from exc
            K, c2w = decompose_projection(P, str(f))
            K[:2, 2] += 0.5
            views.append(SourceView(p.name, p, _camera(K), size, c2w))
        return views, {"poses": str(src / "cameras_P"), "camera_size": list(size)}
    if len(pars) == 1:
        by_name = {p.name: p for p in images}
        lines = [ln.split() for ln in pars[0].read_text().splitlines()[1:] if ln.strip()]
        for k, ln in enumerate(lines):
            where = f"{pars[0]}: line {k + 2}"
            if len(ln) != 22 or ln[0] not in by_name:
                raise InputError(f"{where}: expected 'name k11..k33 r11..r33 t1 t2 t3' naming an image "
                                 f"of {_image_dir(src)}")
            v = np.array(ln[1:], np.float64)
            K, c2w = decompose_projection(v[:9].reshape(3, 3) @ np.hstack([v[9:18].reshape(3, 3),
                                                                            v[18:21, None]]), where)
            K[:2, 2] += 0.5
            p = by_name[ln[0]]
            views.append(SourceView(p.name, p, _camera(K), image_size(p), c2w))
        return sorted(views, key=lambda v: natural_key(v.name)), {"poses": str(pars[0])}
    raise InputError(f"{src}: no projection matrices (cameras_P/ with mvs.ini, or one *_par.txt)")


def _mvs_size(ini: Path) -> tuple[int, int]:
    """(W, H) the AliceVision P matrices are for: mvs.ini's width and height over its scale."""
    cp = configparser.ConfigParser()
    try:
        cp.read_string(ini.read_text())
        g = cp["global"]
        scale = float(g.get("scale", "1"))
        return int(round(float(g["width"]) / scale)), int(round(float(g["height"]) / scale))
    except (OSError, KeyError, ValueError, configparser.Error) as exc:
        raise InputError(f"{ini}: no [global] width, height (and scale) for the projection matrices "
                         f"({exc})") from exc
