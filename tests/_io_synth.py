"""Small synthetic scenes for the io tests: images, cameras on a ring, points."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np

from gs2e.io.scene import Camera, Frame, Scene, opencv_to_opengl

# ../shared/data beside the repo; GS2E_TEST_DATA overrides it (e.g. from a git worktree).
DATA = Path(os.environ.get("GS2E_TEST_DATA",
                           Path(__file__).resolve().parents[1].parent / "shared" / "data"))


def look_at_c2w(centre: np.ndarray, target=np.zeros(3), up=np.array([0.0, 0.0, 1.0])) -> np.ndarray:
    """OpenCV-axes camera-to-world looking from ``centre`` at ``target``."""
    z = target - centre
    z = z / np.linalg.norm(z)
    x = np.cross(z, up)
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, centre
    return T


def ring_poses(n: int, radius: float = 3.0, height: float = 1.0) -> list[np.ndarray]:
    ang = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [look_at_c2w(np.array([radius * np.cos(a), radius * np.sin(a), height + 0.1 * np.sin(3 * a)]))
            for a in ang]


def random_image(rng: np.random.Generator, w: int, h: int) -> np.ndarray:
    """Smooth random uint8 RGB image (H, W, 3)."""
    small = rng.integers(0, 256, size=(max(2, h // 4), max(2, w // 4), 3), dtype=np.uint8)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def write_rgb(path: Path, rgb: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(path), np.ascontiguousarray(rgb[:, :, ::-1]))


def make_scene(n: int = 5, w: int = 48, h: int = 32, camera: Camera | None = None,
               names: list[str] | None = None, seed: int = 0, points: int = 20) -> Scene:
    rng = np.random.default_rng(seed)
    cam = camera or Camera(40.0, 41.0, w / 2 + 0.3, h / 2 - 0.2, "OPENCV", [0.01, -0.002, 1e-4, -2e-4])
    names = names or [f"{i:03d}.png" for i in range(n)]
    frames = [Frame(nm, cam, T) for nm, T in zip(names, ring_poses(n))]
    xyz = rng.normal(size=(points, 3)) * 0.5 if points else None
    rgb = rng.integers(0, 256, size=(points, 3), dtype=np.uint8) if points else None
    return Scene(w, h, frames, "synthetic", "", xyz, rgb)


def write_images(folder: Path, names: list[str], w: int, h: int, seed: int = 0, ext: str | None = None) -> dict:
    """Write distinct random images; returns {name: rgb}."""
    rng = np.random.default_rng(seed)
    out = {}
    for nm in names:
        img = random_image(rng, w, h)
        p = folder / nm
        if ext:
            p = p.with_suffix(ext)
        write_rgb(p, img)
        out[nm] = img
    return out


def write_transforms_gl(path: Path, scene: Scene, file_paths: list[str], extra_top: dict | None = None,
                        transform_world: np.ndarray | None = None) -> None:
    """Hand-written transforms.json in OpenGL convention (global intrinsics from frame 0)."""
    c = scene.frames[0].camera
    top = {"w": scene.width, "h": scene.height, "fl_x": c.fx, "fl_y": c.fy, "cx": c.cx, "cy": c.cy}
    if c.model == "OPENCV":
        top.update(camera_model="OPENCV", k1=c.dist[0], k2=c.dist[1], p1=c.dist[2], p2=c.dist[3])
    frames = []
    for f, fp in zip(scene.frames, file_paths):
        T = opencv_to_opengl(f.c2w)
        if transform_world is not None:
            T = transform_world @ T
        frames.append({"file_path": fp, "transform_matrix": T.tolist()})
    data = {**top, **(extra_top or {}), "frames": frames}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2))


def project(c2w: np.ndarray, cam: Camera, X: np.ndarray) -> np.ndarray:
    """Pinhole projection (no distortion) of world point X (3,) -> pixel (2,)."""
    w2c = np.linalg.inv(c2w)
    p = w2c[:3, :3] @ X + w2c[:3, 3]
    return np.array([cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy])
