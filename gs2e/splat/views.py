"""The scene's posed views as the trainer and the evaluation use them: images
at each downscale factor of the resolution schedule, cameras, the hold-out
split and the scene extent."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from gs2e.common.errors import InputError
from gs2e.common.progress import progress
from gs2e.io.scene import IMAGES_DIR, Scene
from gs2e.splat.rasterize import SplatCamera


@dataclass
class View:
    """One posed view: camera-to-world ``c2w`` (4, 4), intrinsics of the full
    image (px) and the image at each downscale factor."""

    name: str
    c2w: np.ndarray
    fx: float
    fy: float
    cx: float
    cy: float
    images: dict[int, torch.Tensor]  # downscale factor -> (H, W, 3) float32 in [0,1]

    def camera(self, downscale: int) -> tuple[SplatCamera, torch.Tensor]:
        """The camera and image at ``downscale`` (intrinsics scaled to that size)."""
        img = self.images[downscale]
        h, w = img.shape[:2]
        full = self.images[1]
        sx, sy = w / full.shape[1], h / full.shape[0]
        cam = SplatCamera.from_c2w(self.c2w, self.fx * sx, self.fy * sy, self.cx * sx,
                                   self.cy * sy, w, h)
        return cam, img


def downscale_area(img: np.ndarray, downscale: int) -> np.ndarray:
    """``img`` (H, W, ...) area-averaged to (H // d, W // d) (at least 1 px;
    d = 1: ``img`` itself): the size of each step of the resolution schedule."""
    if downscale == 1:
        return img
    import cv2

    h, w = img.shape[:2]
    return cv2.resize(img, (max(1, w // downscale), max(1, h // downscale)), interpolation=cv2.INTER_AREA)


def train_sizes(scene: Scene, max_side: int | str | None,
                target: tuple[int, int] | None = None) -> tuple[tuple[int, int], list[tuple[int, int]]]:
    """The size training works at (``splat.max_side``): (the scene's own size
    after shrinking, (W, H) of each view).

    The scene's own size (:func:`gs2e.io.scene.main_size`) is shrunk to a
    longer side of ``max_side`` px, or with ``"auto"`` to the smallest size
    that still covers ``target`` (the event sensor's array; None: no shrink).
    Every view then gets the angular resolution of those views: view i is
    scaled by s * f_ref / f_i (f: geometric mean focal length in px; f_ref its
    median over the views of the scene's size), so a portrait view of the
    same camera shrinks exactly as the landscape ones and a narrower view
    (a phone's zoom) shrinks less. Never enlarges.
    """
    from gs2e.io.images import cover_max_side, scaled_size

    W, H = int(scene.width), int(scene.height)
    native = [scene.frame_size(i) for i in range(len(scene.frames))]
    side = cover_max_side(W, H, target) if max_side == "auto" else max_side
    if side is None or side >= max(W, H):
        return (W, H), native
    s = side / max(W, H)
    focal = [float(np.sqrt(f.camera.fx * f.camera.fy)) for f in scene.frames]
    f_ref = float(np.median([focal[i] for i in scene.main_frames()]))
    sizes = []
    for (w, h), f_i in zip(native, focal):
        s_i = min(1.0, s * f_ref / f_i)
        sizes.append(scaled_size(w, h, 1, max(1, int(np.ceil(s_i * max(w, h) - 1e-9)))))
    return scaled_size(W, H, 1, side), sizes


def load_views(scene_dir: Path, scene: Scene, downscales: list[int],
               sizes: list[tuple[int, int]] | None = None) -> list[View]:
    """Every frame of ``scene`` (read from ``scene_dir``) with its image at the
    given downscale factors (area-averaged), first resized to ``sizes[i]``
    (W, H) with its intrinsics rescaled exactly (None: the stored size; see
    :func:`train_sizes`). Raises InputError naming the frame when it has no
    pose or a distorted camera."""
    from gs2e.io.images import read_image, resize_with_camera

    views = []
    for i, f in enumerate(progress(scene.frames, desc="loading views")):
        if f.c2w is None:
            raise InputError(f"{scene_dir}: frame {f.name} has no pose; run sfm first")
        if f.camera.model not in ("PINHOLE", "SIMPLE_PINHOLE"):
            raise InputError(f"{scene_dir}: frame {f.name} has a {f.camera.model} camera; "
                             "training needs undistorted PINHOLE views (gs2e sfm output)")
        rgb, cam = read_image(scene_dir / IMAGES_DIR / f.name), f.camera
        if (rgb.shape[1], rgb.shape[0]) != scene.frame_size(i):  # never squeeze a view silently
            raise InputError(f"{scene_dir / IMAGES_DIR / f.name} is {rgb.shape[1]}x{rgb.shape[0]} but "
                             f"{scene_dir / 'scene.json'} says %dx%d" % scene.frame_size(i))
        if sizes is not None:
            rgb, cam, _ = resize_with_camera(rgb, cam, tuple(sizes[i]))
        imgs = {d: torch.from_numpy(downscale_area(rgb, d).astype(np.float32) / 255.0)
                for d in sorted(set(downscales))}
        views.append(View(f.name, f.c2w, cam.fx, cam.fy, cam.cx, cam.cy, imgs))
    return views


def split_views(views: list[View], test_every: int) -> tuple[list[View], list[View]]:
    """Every ``test_every``-th view (in natural name order, as everywhere in
    gs2e, starting with the first) is held out, as the official code's LLFF
    hold-out; 0 disables the split. Both lists are in natural name order."""
    from gs2e.io.views import natural_key

    order = sorted(range(len(views)), key=lambda i: natural_key(views[i].name))
    if test_every <= 0 or len(views) < 3:
        return views, []
    test = {order[i] for i in range(0, len(order), test_every)}
    return [views[i] for i in order if i not in test], [views[i] for i in order if i in test]


def scene_extent(views: list[View]) -> float:
    """1.1 x the largest camera distance from the cameras' centroid (3DGS)."""
    c = np.stack([v.c2w[:3, 3] for v in views])
    r = float(np.max(np.linalg.norm(c - c.mean(0), axis=1)))
    return 1.1 * r if r > 0 else 1.0
