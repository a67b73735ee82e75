"""Shared helpers for the trajectory tests (synthetic poses, temple_ring reader)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gs2e.io.scene import Camera, Frame, Scene

_ROOT = Path(__file__).resolve().parents[1]
# ../shared/data beside the repo; one level further up for git worktrees (wt/<branch>)
DATA = next((p for p in (_ROOT.parent / "shared" / "data", _ROOT.parent.parent / "shared" / "data")
             if p.is_dir()), _ROOT.parent / "shared" / "data")
TEMPLE = DATA / "temple_ring" / "templeR_par.txt"


def look_at(C: np.ndarray, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """c2w (4, 4), OpenCV axes, camera at C looking at target."""
    z = np.asarray(target, float) - C
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], 1)
    T[:3, 3] = C
    return T


def ring(N: int, arc=1.5 * np.pi, radius=3.0, noise=0.0, seed=0) -> np.ndarray:
    """(N, 4, 4) cameras on a ring looking at the origin, optional jitter."""
    rng = np.random.default_rng(seed)
    a = np.linspace(0.0, arc, N)
    C = np.stack([radius * np.cos(a), radius * np.sin(a), 0.5 + 0.3 * np.sin(3 * a)], 1)
    C = C + noise * rng.normal(size=C.shape)
    return np.stack([look_at(c) for c in C])


def make_scene(c2w: np.ndarray, w=64, h=48) -> Scene:
    cam = Camera(50.0, 50.0, w / 2, h / 2)
    return Scene(w, h, [Frame(f"{i:03d}.png", cam, c) for i, c in enumerate(c2w)])


def temple_c2w(n: int | None = None) -> np.ndarray:
    """c2w of the Middlebury templeRing views (world-to-camera R, t in the file)."""
    rows = [ln.split() for ln in TEMPLE.read_text().splitlines()[1:] if ln.strip()]
    out = []
    for r in rows:
        v = np.array(r[1:], float)
        R, t = v[9:18].reshape(3, 3), v[18:21]
        T = np.eye(4)
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ t
        out.append(T)
    c2w = np.stack(out)
    # the file does not list the views in ring order: sort them by their angle
    # around the ring axis (normal of the best-fit plane of the centres)
    C = c2w[:, :3, 3] - c2w[:, :3, 3].mean(0)
    _, _, vt = np.linalg.svd(C)
    ang = np.arctan2(C @ vt[1], C @ vt[0])
    c2w = c2w[np.argsort(ang)]
    if n is not None:
        c2w = c2w[np.linspace(0, len(c2w) - 1, n).round().astype(int)]
    return c2w


def fine_steps(tr, alpha: float, beta_n: float, n: int = 32) -> np.ndarray:
    """Per-step metric arc length (M-1,) of a Trajectory measured independently:
    chords of n sub-steps evaluated through pose_at (time map + arc map + curve)."""
    from gs2e.common.so3 import geodesic_angle

    t = tr.t_us.astype(float)
    tt = t[:-1, None] + np.diff(t)[:, None] * np.linspace(0, 1, n + 1)[None]
    P = tr.pose_at(tt.ravel()).reshape(len(t) - 1, n + 1, 4, 4)
    ang = geodesic_angle(P[:, :-1, :3, :3], P[:, 1:, :3, :3]).sum(1)
    lin = np.linalg.norm(np.diff(P[:, :, :3, 3], axis=1), axis=2).sum(1)
    return alpha * ang + beta_n * lin
