"""Ordering unordered views into a path, and local mini-trajectory windows."""

from __future__ import annotations

import numpy as np

from gs2e.trajectory.order import tour_order
from gs2e.trajectory.settings import TrajectorySettings


def _ring(n: int, radius: float = 3.0) -> np.ndarray:
    """Cameras on a ring looking at the origin (OpenCV axes)."""
    c2w = np.tile(np.eye(4), (n, 1, 1))
    for i, a in enumerate(np.linspace(0, 2 * np.pi, n, endpoint=False)):
        c = np.array([radius * np.cos(a), radius * np.sin(a), 0.5])
        z = -c / np.linalg.norm(c)
        x = np.cross(z, [0, 0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        c2w[i, :3, :3] = np.stack([x, y, z], 1)
        c2w[i, :3, 3] = c
    return c2w


def test_tour_recovers_ring_order_from_a_shuffle():
    n = 40
    ring = _ring(n)
    perm = np.random.default_rng(0).permutation(n)
    order = tour_order(ring[perm])
    visited = perm[order]  # ring indices in path order
    steps = np.abs(np.diff(visited)) % n
    steps = np.minimum(steps, n - steps)
    assert set(visited) == set(range(n))
    assert np.all(steps == 1), f"tour jumps across the ring: {visited}"


def test_tour_small_inputs():
    assert tour_order(_ring(1)).tolist() == [0]
    assert sorted(tour_order(_ring(3)).tolist()) == [0, 1, 2]


def test_stage_orders_unordered_views_and_windows_minis():
    from gs2e.io.scene import Camera, Frame, Scene
    from gs2e.trajectory.stage import generate

    n = 30
    ring = _ring(n)
    perm = np.random.default_rng(1).permutation(n)
    frames = [Frame(f"{i:03d}.png", Camera(300, 300, 160, 120), ring[p]) for i, p in enumerate(perm)]
    scene = Scene(320, 240, frames, "folder")
    cfg = TrajectorySettings.defaults(speed_presets=["medium"], plot=False)
    res = generate(scene, cfg, seed=0)
    base = res.trajectories["base_medium"]
    assert base.meta["view_order"] == "tour"
    # consecutive base poses stay close to the ring (no chord across it)
    centres = base.c2w[:, :3, 3]
    r = np.linalg.norm(centres[:, :2], axis=1)
    assert r.min() > 2.5, "base path cuts through the ring"
    M = len(base.c2w)
    for name, tr in res.trajectories.items():
        if name.startswith("mini"):
            kf = tr.meta["keyframes"]
            assert max(kf) - min(kf) < round(cfg.mini_window * M) + 1
    # explicit sequence order keeps the given (shuffled) order
    cfg_seq = cfg.replace(view_order="sequence")
    assert generate(scene, cfg_seq, seed=0).trajectories["base_medium"].meta["view_order"] == "sequence"


def test_minis_drawn_from_anywhere_on_a_ring_keep_the_object_in_view():
    """The paper draws mini-trajectory keyframes from the whole base path. On a
    ring of views, keyframes from opposite sides join through the object or
    look past it (a real temple_ring run rendered a mini whose view held 1.5 %
    of the object); such draws are redrawn until every pose sees at least
    ``mini_min_view`` of what the base path's poorest view sees."""
    from gs2e.io.scene import Camera, Frame, Scene
    from gs2e.trajectory.stage import generate
    from gs2e.trajectory.trajectory import points_in_view_fraction

    n = 30
    ring = _ring(n)
    frames = [Frame(f"{i:03d}.png", Camera(300, 300, 160, 120), ring[i]) for i in range(n)]
    pts = np.random.default_rng(0).normal(scale=0.3, size=(800, 3))
    scene = Scene(320, 240, frames, "folder", points_xyz=pts)
    K = np.array([[300.0, 0, 160], [0, 300, 120], [0, 0, 1]])
    worst = {}
    for min_view in (0.0, 0.5):
        cfg = TrajectorySettings.defaults(speed_presets=["medium"], plot=False, mini_window=1.0, mini_groups=6,
                                          mini_min_view=min_view)
        res = generate(scene, cfg, seed=3)
        base_min = points_in_view_fraction(pts, res.trajectories["base_medium"].c2w, K, 320, 240).min()
        minis = [tr for name, tr in res.trajectories.items() if name.startswith("mini")]
        worst[min_view] = min(points_in_view_fraction(pts, tr.c2w, K, 320, 240).min() for tr in minis)
        if min_view:
            assert worst[min_view] >= min_view * base_min - 1e-9
            assert any(tr.meta["draws"] > 1 for tr in minis)
            assert all(tr.meta["min_points_in_view"] >= min_view * base_min - 1e-9 for tr in minis)
            again = generate(scene, cfg, seed=3)  # seeded: the same draws
            assert [tr.meta["keyframes"] for name, tr in again.trajectories.items() if name.startswith("mini")] \
                == [tr.meta["keyframes"] for tr in minis]
        else:
            assert all(tr.meta["draws"] == 1 for tr in minis)
    # without the check some novel view loses most of the object
    assert worst[0.0] < 0.5 * worst[0.5], worst
