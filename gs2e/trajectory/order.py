"""Ordering unordered views into a path.

Photos of a plain folder (e.g. a turntable or ring capture sorted by file
name) are not in the order a camera would visit them; a path through them in
name order jumps across the scene and through the object. ``tour_order``
finds a short open path through the poses under the same pose distance the
trajectory uses (alpha * angle + beta * distance / scale): greedy nearest
neighbour from every start, then 2-opt improvement.
"""

from __future__ import annotations

import numpy as np

from gs2e.common.so3 import geodesic_angle
from gs2e.trajectory.curve import translation_scale


def pose_distance_matrix(c2w: np.ndarray, alpha: float, beta: float, normalize: bool = True) -> np.ndarray:
    """(N, N) symmetric pose distances alpha*theta_ij + beta*|T_i - T_j| / scale."""
    R, T = c2w[:, :3, :3], c2w[:, :3, 3]
    n = len(c2w)
    theta = geodesic_angle(np.broadcast_to(R[:, None], (n, n, 3, 3)), np.broadcast_to(R[None], (n, n, 3, 3)))
    scale = translation_scale(c2w) if normalize else 1.0
    dist = np.linalg.norm(T[:, None] - T[None], axis=-1) / (scale if scale > 0 else 1.0)
    return alpha * theta + beta * dist


def _path_length(order: np.ndarray, D: np.ndarray) -> float:
    return float(D[order[:-1], order[1:]].sum())


def _two_opt(order: np.ndarray, D: np.ndarray, max_rounds: int = 50) -> np.ndarray:
    """Reverse segments while that shortens the open path (first improvement)."""
    order = order.copy()
    n = len(order)
    for _ in range(max_rounds):
        improved = False
        for i in range(0, n - 2):
            a, b = order[i], order[i + 1]
            # candidates j > i+1: replace edges (a,b),(c,d) by (a,c),(b,d); d absent at the end
            c = order[i + 2:]
            d = np.append(order[i + 3:], -1)
            gain = D[a, b] + np.where(d >= 0, D[c, np.maximum(d, 0)], 0.0) - D[a, c] - np.where(
                d >= 0, D[b, np.maximum(d, 0)], 0.0)
            k = int(np.argmax(gain))
            if gain[k] > 1e-12:
                j = i + 2 + k
                order[i + 1:j + 1] = order[i + 1:j + 1][::-1]
                improved = True
        if not improved:
            break
    return order


def tour_order(c2w: np.ndarray, alpha: float = 1.0, beta: float = 1.0, normalize: bool = True) -> np.ndarray:
    """Permutation of the N poses giving a short open path (N <= a few thousand)."""
    n = len(c2w)
    if n <= 2:
        return np.arange(n)
    D = pose_distance_matrix(c2w, alpha, beta, normalize)
    best, best_len = None, np.inf
    starts = range(n) if n <= 200 else np.linspace(0, n - 1, 200).astype(int)
    for s in starts:
        seen = np.zeros(n, bool)
        order = [s]
        seen[s] = True
        for _ in range(n - 1):
            row = np.where(seen, np.inf, D[order[-1]])
            nxt = int(np.argmin(row))
            order.append(nxt)
            seen[nxt] = True
        order = np.array(order)
        length = _path_length(order, D)
        if length < best_len:
            best, best_len = order, length
    return _two_opt(best, D)


def is_sequential(scene) -> bool:
    """True if ingestion marked the views as video-ordered (MVImgNet, DL3DV)."""
    ex = scene.extra or {}
    return bool(ex.get("sequential") or (ex.get("input_extra") or {}).get("sequential"))
