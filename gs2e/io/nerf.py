"""NeRF-style ``transforms.json`` (NeRF synthetic, instant-ngp, nerfstudio) <-> Scene.

Conventions of the file format:

- ``transform_matrix`` is camera-to-world with OpenGL camera axes (+x right,
  +y up, +z backward); gs2e converts it with :func:`opengl_to_opencv`.
- Intrinsics are global (top level) or per frame (a frame's keys override the
  top level): ``fl_x``/``fl_y`` in pixels, or ``camera_angle_x`` (and
  ``camera_angle_y``) in radians as the full field of view; ``cx``/``cy``
  (default: image centre), ``w``/``h`` (default: the first image's size).
- Distortion: ``k1, k2, p1, p2`` -> COLMAP OPENCV; ``k3`` non-zero -> FULL_OPENCV
  ``[k1, k2, p1, p2, k3, 0, 0, 0]``; ``camera_model: OPENCV_FISHEYE`` (or
  instant-ngp's ``is_fisheye``) -> OPENCV_FISHEYE ``[k1, k2, k3, k4]``; no
  distortion -> PINHOLE.
- ``file_path`` is relative to the json file's folder, with or without the
  image extension (NeRF synthetic writes ``./train/r_0``).
- nerfstudio's ``ns-process-data`` re-orients the COLMAP world and stores the
  3x4 world transform it applied as ``applied_transform``:
  ``transform_matrix = A @ c2w_colmap``. gs2e undoes it, so poses come back in
  the original (COLMAP) world frame, where a COLMAP model's points live too.
  Other keys (instant-ngp ``aabb_scale``/``scale``/``offset``) are renderer
  settings and are ignored.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from gs2e.common.atomic import write_json_atomic
from gs2e.common.errors import InputError
from gs2e.io.images import IMAGE_EXTS
from gs2e.io.images import image_size as stored_image_size
from gs2e.io.scene import Camera, Scene, check_pose, opencv_to_opengl, opengl_to_opencv
from gs2e.io.views import SourceView, natural_key

_DIST_KEYS = ("k1", "k2", "k3", "k4", "p1", "p2")


def _num(d: dict, key: str, where: str, default=None):
    v = d.get(key, default)
    if v is None:
        return None
    try:
        v = float(v)
    except (TypeError, ValueError):
        raise InputError(f"{where}: '{key}' must be a number, got {v!r}") from None
    if not math.isfinite(v):
        raise InputError(f"{where}: '{key}' is not finite ({v})")
    return v


def resolve_file_path(base: Path, file_path: str) -> Path:
    """Image path for a ``file_path`` entry: as written, else with an image
    extension; where neither exists, the file of that name in ``images/``
    beside the json (captures are often copied flat: nerfstudio's
    ``./images/<capture>/NAME.jpg`` found as ``images/NAME.jpg``)."""
    p = base / file_path
    if not p.is_file() and p.suffix.lower() not in IMAGE_EXTS:
        for ext in IMAGE_EXTS + tuple(e.upper() for e in IMAGE_EXTS):
            q = p.with_name(p.name + ext)
            if q.is_file():
                return q
        p = p.with_name(p.name + ".png")
    if not p.is_file():
        flat = base / "images" / p.name
        if flat.is_file():
            return flat
    return p


def camera_from_entry(d: dict, size: tuple[int, int], where: str) -> Camera:
    """Camera from merged (global + frame) intrinsics keys for an image of ``size`` (W, H)."""
    w, h = size
    fx = _num(d, "fl_x", where)
    fy = _num(d, "fl_y", where)
    ax = _num(d, "camera_angle_x", where)
    ay = _num(d, "camera_angle_y", where)
    if fx is None and ax is not None:
        if not 0 < ax < math.pi:
            raise InputError(f"{where}: camera_angle_x={ax} rad is outside (0, pi)")
        fx = 0.5 * w / math.tan(0.5 * ax)
    if fy is None and ay is not None:
        if not 0 < ay < math.pi:
            raise InputError(f"{where}: camera_angle_y={ay} rad is outside (0, pi)")
        fy = 0.5 * h / math.tan(0.5 * ay)
    if fx is None and fy is None:
        raise InputError(f"{where}: no focal length (fl_x/fl_y or camera_angle_x)")
    fx = fy if fx is None else fx
    fy = fx if fy is None else fy
    cx = _num(d, "cx", where, 0.5 * w)
    cy = _num(d, "cy", where, 0.5 * h)
    k = {key: _num(d, key, where, 0.0) for key in _DIST_KEYS}
    model_name = str(d.get("camera_model", "OPENCV")).upper()
    if d.get("is_fisheye") or model_name == "OPENCV_FISHEYE":
        model, dist = "OPENCV_FISHEYE", [k["k1"], k["k2"], k["k3"], k["k4"]]
    elif model_name in ("OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "PERSPECTIVE"):
        if k["k4"] != 0.0:
            raise InputError(f"{where}: k4 is only supported with camera_model OPENCV_FISHEYE")
        if k["k3"] != 0.0:
            model, dist = "FULL_OPENCV", [k["k1"], k["k2"], k["p1"], k["p2"], k["k3"], 0.0, 0.0, 0.0]
        elif any(k[x] != 0.0 for x in ("k1", "k2", "p1", "p2")):
            model, dist = "OPENCV", [k["k1"], k["k2"], k["p1"], k["p2"]]
        else:
            model, dist = "PINHOLE", []
    else:
        raise InputError(f"{where}: unsupported camera_model '{model_name}'")
    try:
        return Camera(fx, fy, cx, cy, model, dist)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from exc


def load_transforms_json(path: str | os.PathLike) -> dict:
    """Parse a transforms.json; InputError naming the file if unreadable/invalid."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"transforms file {path} does not exist")
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read transforms file {path}: {exc}") from exc
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise InputError(f"transforms file {path} has no 'frames' list")
    return data


def applied_transform_matrix(data: dict, where: str) -> np.ndarray | None:
    """nerfstudio's ``applied_transform`` as a 4x4 (None if absent)."""
    if "applied_transform" not in data:
        return None
    A = np.asarray(data["applied_transform"], dtype=np.float64)
    if A.shape == (3, 4):
        A = np.vstack([A, [0, 0, 0, 1]])
    if A.shape != (4, 4) or not np.all(np.isfinite(A)) or abs(np.linalg.det(A)) < 1e-12:
        raise InputError(f"{where}: applied_transform must be an invertible finite 3x4 matrix")
    return A


def views_from_transforms(data: dict, base: Path, where: str,
                          image_size: tuple[int, int] | None = None) -> list[SourceView]:
    """SourceViews (OpenCV c2w in the source's original world) of a parsed transforms.json.

    ``base``: folder file_paths are relative to. ``image_size`` (W, H) is used when
    the json gives no w/h; if None, each such frame's own image header gives
    its size (frames of one file may differ: landscape and portrait photos
    with per-frame intrinsics).
    """
    A = applied_transform_matrix(data, where)
    A_inv = None if A is None else np.linalg.inv(A)
    top = {k: v for k, v in data.items() if k != "frames"}
    views = []
    for i, fr in enumerate(data["frames"]):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise InputError(f"{where}: frame {i} needs 'file_path' and 'transform_matrix'")
        fp = str(fr["file_path"])
        fwhere = f"{where}: frame {i} ({fp})"
        merged = {**top, **fr}
        path = resolve_file_path(base, fp)
        w, h = _num(merged, "w", fwhere), _num(merged, "h", fwhere)
        if w is None or h is None:
            w, h = image_size if image_size is not None else stored_image_size(path)
        size = (int(round(w)), int(round(h)))
        if size[0] <= 0 or size[1] <= 0:
            raise InputError(f"{fwhere}: invalid image size w={w} h={h}")
        cam = camera_from_entry(merged, size, fwhere)
        try:
            T = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError(f"{fwhere}: transform_matrix is not a numeric matrix") from None
        c2w_gl = check_pose(T, fwhere)
        c2w = opengl_to_opencv(c2w_gl)
        if A_inv is not None:
            c2w = check_pose(A_inv @ c2w, fwhere + " after undoing applied_transform")
        name = fp[2:] if fp.startswith("./") else fp
        views.append(SourceView(name, path, cam, size, c2w))
    return views


def read_transforms_views(path: str | os.PathLike,
                          image_size: tuple[int, int] | None = None) -> list[SourceView]:
    """SourceViews of a transforms.json file, sorted by name (natural order)."""
    path = Path(path)
    data = load_transforms_json(path)
    views = views_from_transforms(data, path.parent, str(path), image_size)
    return sorted(views, key=lambda v: natural_key(v.name))


def read_transforms(path: str | os.PathLike, image_size: tuple[int, int] | None = None) -> Scene:
    """Scene (frames sorted by name, names = file_path) from a transforms.json file."""
    from gs2e.io.colmap import scene_from_views

    views = read_transforms_views(path, image_size)
    return scene_from_views(views, "nerf", str(path))


def transforms_from_scene(scene: Scene, image_prefix: str = "images/") -> dict:
    """transforms.json content for a Scene (OpenGL c2w, nerfstudio keys).

    Intrinsics are written at the top level when all frames share them, per
    frame otherwise. SIMPLE_RADIAL/RADIAL are written as the equivalent OPENCV
    parameters. ``file_path`` = image_prefix + frame name.
    """
    if not scene.has_poses:
        raise InputError("transforms.json needs a pose for every frame")
    def intr(i: int) -> dict:
        c = scene.frames[i].camera
        w, h = scene.frame_size(i)
        d = {"w": int(w), "h": int(h), "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy,
             "camera_angle_x": 2.0 * math.atan(0.5 * w / c.fx),
             "camera_angle_y": 2.0 * math.atan(0.5 * h / c.fy)}
        dist = list(c.dist)
        if c.model == "OPENCV_FISHEYE":
            d["camera_model"] = "OPENCV_FISHEYE"
            d.update(zip(("k1", "k2", "k3", "k4"), dist))
            return d
        d["camera_model"] = "OPENCV"
        if c.model == "SIMPLE_RADIAL":
            dist = [dist[0], 0.0, 0.0, 0.0]
        elif c.model == "RADIAL":
            dist = [dist[0], dist[1], 0.0, 0.0]
        elif c.model == "FULL_OPENCV":
            if any(x != 0.0 for x in dist[5:]):
                raise InputError(f"frame {scene.frames[i].name}: FULL_OPENCV k4..k6 cannot be written to transforms.json")
            d["k3"] = dist[4]
            dist = dist[:4]
        if dist:
            d.update(zip(("k1", "k2", "p1", "p2"), dist))
        return d

    per = [intr(i) for i in range(len(scene.frames))]
    shared = all(p == per[0] for p in per)
    out: dict = dict(per[0]) if shared else {}
    frames = []
    for f, p in zip(scene.frames, per):
        fr = {"file_path": image_prefix + f.name,
              "transform_matrix": opencv_to_opengl(f.c2w).tolist()}
        if not shared:
            fr.update(p)
        frames.append(fr)
    out["frames"] = frames
    return out


def write_transforms(scene: Scene, path: str | os.PathLike, image_prefix: str = "images/") -> None:
    """Write a Scene as transforms.json (atomically); see :func:`transforms_from_scene`."""
    write_json_atomic(path, transforms_from_scene(scene, image_prefix))
