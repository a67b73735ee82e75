"""The internal scene layout every stage reads and writes.

A scene folder holds::

    images/<name>          8-bit RGB images (PNG), all the same resolution
    scene.json             cameras, poses and provenance (below)
    points3d.npz           optional sparse points: xyz (P,3) float64, rgb (P,3) uint8

``scene.json``::

    {"format": "gs2e-scene", "version": 1,
     "layout": "<source layout>", "source": "<source path>",
     "width": W, "height": H,
     "frames": [{"name": "000.png",
                 "camera": {"model": "PINHOLE", "fx":.., "fy":.., "cx":.., "cy":..,
                            "dist": [..]},        # model-specific distortion, may be []
                 "c2w": [[4x4]] or null}],        # camera-to-world, OpenCV axes
     "has_poses": bool, "extra": {...}}

Conventions (one of each, everywhere in gs2e):
- Camera axes are OpenCV: +x right, +y down, +z forward (viewing direction).
- Poses are camera-to-world 4x4 matrices ``c2w``; ``w2c = inv(c2w)``.
- Pixel centres are at integer + 0.5 in the continuous image coordinates used by
  ``cx, cy`` (COLMAP's convention): the top-left pixel covers [0,1)x[0,1).
- Distortion models and parameter order follow COLMAP: SIMPLE_PINHOLE/PINHOLE
  (none), SIMPLE_RADIAL [k], RADIAL [k1,k2], OPENCV [k1,k2,p1,p2],
  OPENCV_FISHEYE [k1,k2,k3,k4], FULL_OPENCV [k1,k2,p1,p2,k3,k4,k5,k6].
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gs2e.common.errors import InputError

SCENE_JSON = "scene.json"
POINTS_NPZ = "points3d.npz"
IMAGES_DIR = "images"

DIST_PARAMS = {
    "SIMPLE_PINHOLE": 0,
    "PINHOLE": 0,
    "SIMPLE_RADIAL": 1,
    "RADIAL": 2,
    "OPENCV": 4,
    "OPENCV_FISHEYE": 4,
    "FULL_OPENCV": 8,
}


@dataclass
class Camera:
    """Intrinsics in pixels (OpenCV/COLMAP convention) and distortion."""

    fx: float
    fy: float
    cx: float
    cy: float
    model: str = "PINHOLE"
    dist: list[float] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.model not in DIST_PARAMS:
            raise InputError(f"unsupported camera model '{self.model}'")
        if len(self.dist) != DIST_PARAMS[self.model]:
            raise InputError(
                f"camera model {self.model} takes {DIST_PARAMS[self.model]} distortion "
                f"parameters, got {len(self.dist)}")
        vals = [self.fx, self.fy, self.cx, self.cy, *self.dist]
        if not all(math.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise InputError(f"invalid intrinsics fx={self.fx} fy={self.fy} cx={self.cx} cy={self.cy}")

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def scaled(self, sx: float, sy: float) -> "Camera":
        """Intrinsics after resizing the image by (sx, sy) (pixel-centre convention)."""
        return Camera(self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy, self.model, list(self.dist))

    def to_dict(self) -> dict:
        return {"model": self.model, "fx": self.fx, "fy": self.fy, "cx": self.cx,
                "cy": self.cy, "dist": list(self.dist)}

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        return cls(float(d["fx"]), float(d["fy"]), float(d["cx"]), float(d["cy"]),
                   d.get("model", "PINHOLE"), [float(x) for x in d.get("dist", [])])


@dataclass
class Frame:
    name: str
    camera: Camera
    c2w: np.ndarray | None = None  # (4, 4) float64, OpenCV axes

    def __post_init__(self) -> None:
        if self.c2w is not None:
            self.c2w = check_pose(self.c2w, self.name)


@dataclass
class Scene:
    """A scene in the internal layout (images are stored on disk, not here)."""

    width: int
    height: int
    frames: list[Frame]
    layout: str = "unknown"
    source: str = ""
    points_xyz: np.ndarray | None = None  # (P, 3) float64
    points_rgb: np.ndarray | None = None  # (P, 3) uint8
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def has_poses(self) -> bool:
        return bool(self.frames) and all(f.c2w is not None for f in self.frames)

    def frame_size(self, i: int) -> tuple[int, int]:
        """(W, H) of frame ``i``: its own size (``extra["frame_sizes"]``) when
        the views differ in size or orientation, else the scene's."""
        sizes = self.extra.get("frame_sizes")
        if sizes and sizes[i]:
            return int(sizes[i][0]), int(sizes[i][1])
        return int(self.width), int(self.height)

    def main_frames(self) -> list[int]:
        """Indices of the frames of the scene's own size (see :func:`main_size`)."""
        size = (int(self.width), int(self.height))
        return [i for i in range(len(self.frames)) if self.frame_size(i) == size] or [0]

    def main_K(self) -> np.ndarray:
        """(3, 3) element-wise median intrinsics of the frames of the scene's own
        size: the camera of its virtual trajectories where a frame of another size
        or orientation lends only its pose (phones change focal length per shot)."""
        return np.median(np.stack([self.frames[i].camera.K for i in self.main_frames()]), axis=0)

    def c2w_array(self) -> np.ndarray:
        """(N, 4, 4) camera-to-world poses; raises if any frame lacks one."""
        if not self.has_poses:
            raise InputError("scene has frames without poses")
        return np.stack([f.c2w for f in self.frames])


def main_size(sizes: list[tuple[int, int]]) -> tuple[int, int]:
    """The most common (W, H) of ``sizes`` (a tie: the one seen first): a scene's
    own size, the size and orientation of the camera its virtual trajectories use.
    Views of other sizes or orientations keep theirs (``extra["frame_sizes"]``)."""
    counts: dict[tuple[int, int], int] = {}
    for s in sizes:
        counts[tuple(s)] = counts.get(tuple(s), 0) + 1
    return max(counts, key=counts.__getitem__)  # max keeps the first of equal counts


def with_frame_sizes(extra: dict, sizes: list[tuple[int, int]], main: tuple[int, int]) -> dict:
    """``extra`` with ``frame_sizes`` set when any size differs from ``main``
    (dropped otherwise)."""
    out = {k: v for k, v in extra.items() if k != "frame_sizes"}
    if any(tuple(s) != tuple(main) for s in sizes):
        out["frame_sizes"] = [[int(w), int(h)] for w, h in sizes]
    return out


def check_pose(c2w: Any, name: str = "pose") -> np.ndarray:
    """Validate a 4x4 rigid transform (finite, orthonormal rotation, det +1)."""
    T = np.asarray(c2w, dtype=np.float64)
    if T.shape == (3, 4):
        T = np.vstack([T, [0, 0, 0, 1]])
    if T.shape != (4, 4):
        raise InputError(f"{name}: pose must be 4x4 (or 3x4), got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise InputError(f"{name}: pose contains NaN or inf")
    R = T[:3, :3]
    err = np.abs(R @ R.T - np.eye(3)).max()
    if err > 1e-4 or np.linalg.det(R) < 0:
        raise InputError(f"{name}: pose rotation is not a proper rotation (|RR^T-I|={err:.2e}, det={np.linalg.det(R):.3f})")
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise InputError(f"{name}: last pose row must be [0,0,0,1]")
    return T


def write_scene_json(scene: Scene, folder: Path) -> None:
    """Write scene.json (+ points3d.npz) into ``folder`` (the caller makes it atomic)."""
    folder = Path(folder)
    data = {
        "format": "gs2e-scene",
        "version": 1,
        "layout": scene.layout,
        "source": scene.source,
        "width": int(scene.width),
        "height": int(scene.height),
        "has_poses": scene.has_poses,
        "frames": [
            {"name": f.name, "camera": f.camera.to_dict(),
             "c2w": None if f.c2w is None else f.c2w.tolist()}
            for f in scene.frames
        ],
        "extra": scene.extra,
    }
    (folder / SCENE_JSON).write_text(json.dumps(data, indent=1, allow_nan=False) + "\n")
    if scene.points_xyz is not None:
        np.savez_compressed(folder / POINTS_NPZ, xyz=np.asarray(scene.points_xyz, np.float64),
                            rgb=np.asarray(scene.points_rgb if scene.points_rgb is not None
                                           else np.full((len(scene.points_xyz), 3), 128), np.uint8))


def read_scene(folder: str | Path) -> Scene:
    """Read a scene folder written by :func:`write_scene_json`."""
    folder = Path(folder)
    path = folder / SCENE_JSON
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read scene file {path}: {exc}") from exc
    if data.get("format") != "gs2e-scene":
        raise InputError(f"{path}: not a gs2e scene file")
    frames = []
    for i, fd in enumerate(data["frames"]):
        frames.append(Frame(fd["name"], Camera.from_dict(fd["camera"]),
                            None if fd.get("c2w") is None else np.array(fd["c2w"], dtype=np.float64)))
    xyz = rgb = None
    if (folder / POINTS_NPZ).exists():
        try:
            with np.load(folder / POINTS_NPZ) as z:
                xyz, rgb = z["xyz"].astype(np.float64), z["rgb"].astype(np.uint8)
        except Exception as exc:  # corrupt npz
            raise InputError(f"cannot read {folder / POINTS_NPZ}: {exc}") from exc
    return Scene(int(data["width"]), int(data["height"]), frames, data.get("layout", "unknown"),
                 data.get("source", ""), xyz, rgb, data.get("extra", {}))


def opengl_to_opencv(c2w_gl: np.ndarray) -> np.ndarray:
    """Convert camera-to-world poses from OpenGL/NeRF axes (+y up, +z backward)
    to OpenCV axes (+y down, +z forward): flip the camera's y and z columns.
    The conversion is its own inverse. Shape (..., 4, 4)."""
    T = np.array(c2w_gl, dtype=np.float64, copy=True)
    T[..., :3, 1:3] *= -1
    return T


opencv_to_opengl = opengl_to_opencv
