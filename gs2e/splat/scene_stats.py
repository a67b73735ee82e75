"""What a scene needs: SH degree from observed view dependence, Gaussian budget
from image detail. Both are measured on the SfM output before training."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gs2e.common.log import get_logger

log = get_logger("gs2e.splat")


def view_dependence(model_dir: str | Path, image_dir: str | Path, max_points: int = 3000,
                    min_track: int = 3, seed: int = 0) -> float | None:
    """Median over SfM points of the relative colour spread across the views
    that observed them: std(luminance) / mean(luminance) along each track,
    sampled at the exact 2D observations (no visibility guess needed).

    Near 0 for Lambertian scenes (view-independent colour); larger values
    mean specularities or exposure changes that higher SH degrees can model.
    Returns None when the model has no tracks (e.g. a drop-in model).
    """
    import cv2
    import pycolmap

    model_dir, image_dir = Path(model_dir), Path(image_dir)
    try:
        rec = pycolmap.Reconstruction(str(model_dir))
    except Exception:  # no COLMAP model: nothing to measure
        return None
    pids = [pid for pid, p in rec.points3D.items() if p.track.length() >= min_track]
    if not pids:
        return None
    rng = np.random.default_rng(seed)
    if len(pids) > max_points:
        pids = list(rng.choice(pids, size=max_points, replace=False))
    cache: dict[int, np.ndarray] = {}
    spreads = []
    for pid in pids:
        lum = []
        for el in rec.points3D[pid].track.elements:
            img = cache.get(el.image_id)
            if img is None:
                im = rec.image(el.image_id)
                bgr = cv2.imread(str(image_dir / im.name), cv2.IMREAD_COLOR)
                if bgr is None:
                    continue
                img = cache[el.image_id] = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255
            xy = rec.image(el.image_id).points2D[el.point2D_idx].xy
            x, y = int(xy[0]), int(xy[1])  # pixel containing the keypoint (centres at +0.5)
            if 0 <= y < img.shape[0] and 0 <= x < img.shape[1]:
                lum.append(img[y, x])
        if len(lum) >= min_track:
            lum = np.asarray(lum)
            if lum.mean() > 0.02:  # relative spread of near-black points is noise
                spreads.append(lum.std() / lum.mean())
    return float(np.median(spreads)) if spreads else None


def choose_sh_degree(score: float | None, thresholds: list[float], max_degree: int = 3) -> int:
    """Degree d = number of thresholds the score exceeds (None -> max_degree)."""
    if score is None:
        return max_degree
    return int(min(max_degree, sum(score > t for t in thresholds)))


def detail_budget(images: list[np.ndarray], per_edge_pixel: float, lo: int, hi: int,
                  grad_threshold: float = 0.08) -> tuple[int, float]:
    """Gaussian budget from image detail: ``per_edge_pixel`` x the median number
    of pixels whose luminance gradient exceeds ``grad_threshold`` (per unit,
    images in [0,1]), clipped to [lo, hi]. Returns (budget, median edge count)."""
    import cv2

    counts = []
    for im in images:
        g = cv2.cvtColor(np.asarray(im, np.float32), cv2.COLOR_RGB2GRAY)
        gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8
        gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8
        counts.append(int((np.hypot(gx, gy) > grad_threshold).sum()))
    med = float(np.median(counts)) if counts else 0.0
    return int(np.clip(per_edge_pixel * med, lo, hi)), med
