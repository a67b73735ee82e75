"""COLMAP sparse models <-> the internal :class:`~gs2e.io.scene.Scene`.

A COLMAP model folder holds cameras, images and points3D as ``.bin`` or
``.txt`` (COLMAP >= 3.12 adds rigs and frames; older models without them are
read too). pycolmap reads both formats.

Conventions: COLMAP stores ``cam_from_world`` (world-to-camera) with OpenCV
camera axes; gs2e stores ``c2w = inv(cam_from_world)`` with the same axes. The
camera models and their parameter order are COLMAP's, so
``Camera.dist`` is COLMAP's parameter list after the focal lengths and the
principal point.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Iterable

import numpy as np
import pycolmap

from gs2e.common.atomic import atomic_dir
from gs2e.common.errors import InputError
from gs2e.io.scene import Camera, Frame, Scene, check_pose, main_size, with_frame_sizes
from gs2e.io.views import SourceView, natural_key

# COLMAP model name -> (single focal length?, number of distortion params)
_MODELS = {
    "SIMPLE_PINHOLE": (True, 0),
    "PINHOLE": (False, 0),
    "SIMPLE_RADIAL": (True, 1),
    "RADIAL": (True, 2),
    "OPENCV": (False, 4),
    "OPENCV_FISHEYE": (False, 4),
    "FULL_OPENCV": (False, 8),
}
MODEL_FILES = ("cameras", "images", "points3D")


def camera_from_colmap(cam: pycolmap.Camera, where: str = "COLMAP model") -> Camera:
    """gs2e Camera from a pycolmap Camera (same model, COLMAP parameter order)."""
    name = cam.model.name
    if name not in _MODELS:
        raise InputError(f"{where}: camera {cam.camera_id} has unsupported model {name} "
                         f"(supported: {', '.join(_MODELS)})")
    single, ndist = _MODELS[name]
    p = [float(x) for x in cam.params]
    if single:
        fx = fy = p[0]
        cx, cy, dist = p[1], p[2], p[3:]
    else:
        fx, fy, cx, cy, dist = p[0], p[1], p[2], p[3], p[4:]
    if len(dist) != ndist:
        raise InputError(f"{where}: camera {cam.camera_id} ({name}) has {len(p)} parameters")
    try:
        return Camera(fx, fy, cx, cy, name, dist)
    except InputError as exc:
        raise InputError(f"{where}: camera {cam.camera_id}: {exc}") from exc


def camera_to_colmap(cam: Camera, width: int, height: int, camera_id: int) -> pycolmap.Camera:
    """pycolmap Camera for a gs2e Camera; single-focal models need fx == fy."""
    single, _ = _MODELS[cam.model]
    if single:
        if not np.isclose(cam.fx, cam.fy, rtol=1e-12, atol=0):
            raise InputError(f"camera model {cam.model} has one focal length, got fx={cam.fx} fy={cam.fy}")
        params = [cam.fx, cam.cx, cam.cy, *cam.dist]
    else:
        params = [cam.fx, cam.fy, cam.cx, cam.cy, *cam.dist]
    return pycolmap.Camera(model=cam.model, width=int(width), height=int(height),
                           params=params, camera_id=int(camera_id))


def c2w_from_rigid(cam_from_world: pycolmap.Rigid3d) -> np.ndarray:
    """(4, 4) camera-to-world from COLMAP's cam_from_world."""
    w2c = np.eye(4)
    w2c[:3, :4] = np.asarray(cam_from_world.matrix(), dtype=np.float64)
    R, t = w2c[:3, :3], w2c[:3, 3]
    c2w = np.eye(4)
    c2w[:3, :3] = R.T
    c2w[:3, 3] = -R.T @ t
    return c2w


def rigid_from_c2w(c2w: np.ndarray) -> pycolmap.Rigid3d:
    """COLMAP cam_from_world from a (4, 4) camera-to-world."""
    R, C = c2w[:3, :3], c2w[:3, 3]
    m = np.hstack([R.T, (-R.T @ C)[:, None]])
    return pycolmap.Rigid3d(m)


def find_model_dir(folder: str | os.PathLike) -> Path | None:
    """The folder itself, ``sparse/0`` or ``sparse`` under it, whichever holds a model."""
    folder = Path(folder)
    for cand in (folder, folder / "sparse" / "0", folder / "sparse"):
        if is_model_dir(cand):
            return cand
    return None


def is_model_dir(folder: str | os.PathLike) -> bool:
    """True if ``folder`` has cameras/images/points3D in .bin or in .txt."""
    folder = Path(folder)
    return any(all((folder / f"{m}.{ext}").is_file() for m in MODEL_FILES) for ext in ("bin", "txt"))


def load_reconstruction(model_dir: str | os.PathLike) -> pycolmap.Reconstruction:
    """Read a COLMAP model folder; InputError naming the folder/file on failure."""
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError(f"COLMAP model folder {model_dir} does not exist")
    if not is_model_dir(model_dir):
        raise InputError(f"COLMAP model folder {model_dir} lacks cameras, images and points3D "
                         f"(.bin or .txt)")
    for m in MODEL_FILES:
        for ext in ("bin", "txt"):
            f = model_dir / f"{m}.{ext}"
            if f.is_file() and ext == "bin" and f.stat().st_size == 0:
                raise InputError(f"COLMAP model file {f} is empty")
    try:
        return pycolmap.Reconstruction(str(model_dir))
    except (ValueError, RuntimeError, OSError) as exc:
        raise InputError(f"cannot read COLMAP model {model_dir}: {exc}") from exc


def views_from_reconstruction(rec: pycolmap.Reconstruction, image_dir: str | os.PathLike | None = None,
                              where: str = "COLMAP model") -> list[SourceView]:
    """One SourceView per registered image (with a pose), sorted by name.

    ``path`` is ``image_dir / name`` (``name`` if image_dir is None).
    """
    base = Path(image_dir) if image_dir is not None else Path()
    cams: dict[int, Camera] = {}
    views = []
    for image in rec.images.values():
        if not image.has_pose:
            continue
        cid = image.camera_id
        if cid not in cams:
            cams[cid] = camera_from_colmap(rec.cameras[cid], where)
        c = rec.cameras[cid]
        try:
            c2w = check_pose(c2w_from_rigid(image.cam_from_world()), f"{where}: image {image.name}")
        except ValueError as exc:
            raise InputError(f"{where}: image {image.name}: invalid pose ({exc})") from exc
        views.append(SourceView(image.name, base / image.name, cams[cid],
                                (int(c.width), int(c.height)), c2w))
    views.sort(key=lambda v: natural_key(v.name))
    return views


def points_from_reconstruction(rec: pycolmap.Reconstruction) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(P, 3) float64 xyz and (P, 3) uint8 rgb ordered by point id (None if no points)."""
    if rec.num_points3D() == 0:
        return None, None
    ids = sorted(rec.point3D_ids())
    pts = rec.points3D
    xyz = np.array([pts[i].xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    rgb = np.array([pts[i].color for i in ids], dtype=np.uint8).reshape(-1, 3)
    return xyz, rgb


def scene_from_views(views: list[SourceView], layout: str = "colmap", source: str = "",
                     points: tuple[np.ndarray | None, np.ndarray | None] = (None, None)) -> Scene:
    """Scene from SourceViews: width/height are the most common view size
    (:func:`gs2e.io.scene.main_size`); if views differ in size or orientation,
    ``extra['frame_sizes']`` lists (W, H) per frame."""
    if not views:
        return Scene(0, 0, [], layout, source, points[0], points[1])
    frames = [Frame(v.name, v.camera, v.c2w) for v in views]
    sizes = [tuple(v.size) if v.size else (0, 0) for v in views]
    w, h = main_size(sizes)
    return Scene(int(w), int(h), frames, layout, source, points[0], points[1],
                 with_frame_sizes({}, sizes, (w, h)))


def scene_from_reconstruction(rec: pycolmap.Reconstruction, names: Iterable[str] | None = None) -> Scene:
    """Internal Scene of the registered images of a pycolmap Reconstruction.

    Parameters
    ----------
    rec : the reconstruction (pycolmap 4; images without a pose are skipped).
    names : optional image names; if given, the frames follow this order and
        names not registered in ``rec`` are skipped. Default: all registered
        images sorted by name (natural order, i.e. numbers compare numerically).

    Returns
    -------
    Scene with frame names = COLMAP image names, cameras mapped with their
    distortion (COLMAP order), c2w = inv(cam_from_world) (OpenCV axes),
    width/height from the cameras, points3D xyz (P,3) float64 + rgb (P,3) uint8.
    """
    views = views_from_reconstruction(rec)
    if names is not None:
        by_name = {v.name: v for v in views}
        views = [by_name[n] for n in names if n in by_name]
    return scene_from_views(views, "colmap", "", points_from_reconstruction(rec))


def reconstruction_from_scene(scene: Scene) -> pycolmap.Reconstruction:
    """pycolmap Reconstruction of a Scene: one camera per distinct intrinsics
    (ids 1.. in order of first use), image ids 1..N in frame order, frames with
    a pose registered (cam_from_world = inv(c2w)), points3D (empty tracks) when
    ``scene.points_xyz`` exists.
    """
    rec = pycolmap.Reconstruction()
    cam_ids: dict[tuple, int] = {}
    for i, f in enumerate(scene.frames):
        w, h = scene.frame_size(i)
        c = f.camera
        key = (c.model, c.fx, c.fy, c.cx, c.cy, tuple(c.dist), int(w), int(h))
        if key not in cam_ids:
            cam_ids[key] = len(cam_ids) + 1
            rec.add_camera_with_trivial_rig(camera_to_colmap(c, w, h, cam_ids[key]))
        image = pycolmap.Image(name=f.name, camera_id=cam_ids[key], image_id=i + 1)
        if f.c2w is not None:
            rec.add_image_with_trivial_frame(image, rigid_from_c2w(f.c2w))
        else:
            rec.add_image_with_trivial_frame(image)
    if scene.points_xyz is not None:
        xyz = np.asarray(scene.points_xyz, np.float64).reshape(-1, 3)
        rgb = (np.asarray(scene.points_rgb, np.uint8).reshape(-1, 3) if scene.points_rgb is not None
               else np.full((len(xyz), 3), 128, np.uint8))
        for p, c in zip(xyz, rgb):
            rec.add_point3D(p, pycolmap.Track(), c)
    return rec


def read_colmap_model(model_dir: str | os.PathLike) -> Scene:
    """Read a COLMAP sparse model folder (.bin or .txt) into a Scene.

    Frames are the registered images ordered by name; see
    :func:`scene_from_reconstruction`. ``scene.source`` is the folder.
    """
    model_dir = Path(model_dir)
    rec = load_reconstruction(model_dir)
    views = views_from_reconstruction(rec, None, str(model_dir))
    return scene_from_views(views, "colmap", str(model_dir), points_from_reconstruction(rec))


def write_colmap_model(scene: Scene, model_dir: str | os.PathLike, binary: bool = True) -> None:
    """Write a Scene as a COLMAP model folder (binary or text), atomically."""
    rec = reconstruction_from_scene(scene)
    with atomic_dir(model_dir) as tmp:
        if binary:
            rec.write(str(tmp))
        else:
            rec.write_text(str(tmp))
