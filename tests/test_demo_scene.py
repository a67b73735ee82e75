"""The built-in demo scene: textures, ray caster, cameras, output layout."""

from __future__ import annotations

import socket

import numpy as np
import pytest
from PIL import Image

from gs2e.cli import main as gs2e_main
from gs2e.common.errors import ConfigError
from gs2e.common.so3 import geodesic_angle
from gs2e.demo.settings import DemoSettings
from gs2e.demo import geometry as geo
from gs2e.demo.io import generate_demo_scene
from gs2e.demo.textures import BUNDLED_PHOTOS, build_atlas, load_photo
from gs2e.demo.world import (TARGET, build_world, camera_rays, cast, check_orbit, intrinsics,
                             orbit_c2w, render_view, wall_size)
from gs2e.io.scene import check_pose, read_scene
from tests.conftest import REPO

SMALL = {"n_views": 8, "width": 96, "height": 72, "n_points": 2000}


def cfg(**over) -> DemoSettings:
    return DemoSettings.defaults(**{**SMALL, **over})


def soa(a) -> np.ndarray:
    """(N, 3) -> (3, N) float32, the ray caster's layout."""
    return np.ascontiguousarray(np.asarray(a, np.float64).reshape(-1, 3).T, np.float32)


# ----------------------------------------------------------------------------- textures

def test_bundled_photos_load_without_network(monkeypatch):
    def no_network(*args, **kwargs):
        raise OSError("network access attempted")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    monkeypatch.setattr(socket, "create_connection", no_network)
    for name in BUNDLED_PHOTOS:
        img = load_photo(name)
        assert img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3, name
        assert min(img.shape[:2]) >= 170, name
    atlas = build_atlas(BUNDLED_PHOTOS, 64)
    assert atlas.tex.shape == (len(BUNDLED_PHOTOS), 64, 64, 3)
    # every texture carries structure (SIFT needs it), none is flat
    assert np.all(atlas.tex.reshape(len(BUNDLED_PHOTOS), -1).std(axis=1) > 0.08)


def test_atlas_lookup_is_bilinear_with_texel_centres():
    atlas = build_atlas(("astronaut",), 32)
    pid = atlas.add_patch("astronaut")
    S = 32
    # u = (j + 0.5) / S hits texel j exactly
    j, i = np.array([0, 5, 31]), np.array([3, 17, 0])
    got = atlas.lookup(np.full(3, pid), (j + 0.5) / S, (i + 0.5) / S).T
    np.testing.assert_allclose(got, atlas.tex[0, i, j], atol=1e-6)
    # halfway between two texels: their mean
    mid = atlas.lookup(np.array([pid]), np.array([(5 + 1.0) / S]), np.array([(17 + 0.5) / S])).T[0]
    np.testing.assert_allclose(mid, (atlas.tex[0, 17, 5] + atlas.tex[0, 17, 6]) / 2, atol=1e-6)
    # tint and a quarter turn: rot=2 maps (u, v) to (1-u, 1-v)
    p2 = atlas.add_patch("astronaut", tint=(0.5, 1.0, 0.25), rot=2)
    got2 = atlas.lookup(np.array([p2]), np.array([1 - 5.5 / S]), np.array([1 - 17.5 / S])).T[0]
    np.testing.assert_allclose(got2, atlas.tex[0, 17, 5] * [0.5, 1.0, 0.25], atol=1e-6)


# ----------------------------------------------------------------------------- geometry

def test_box_intersection_rotated_and_axis_parallel_rays():
    box = geo.Box(centre=[1.0, 2.0, 0.5], half=[0.5, 0.25, 0.5], yaw=np.radians(90), patches=(0,) * 6)
    # yaw 90 deg: local x runs along world y, so the world-x half extent is 0.25
    o = soa([[-3.0, 2.0, 0.5], [1.0, 2.0, 3.0], [1.0, 5.0, 0.5], [-3.0, 2.6, 0.5], [1.0, 2.0, 0.5]])
    d = soa([[1.0, 0, 0], [0, 0, -1.0], [0, -1.0, 0], [1.0, 0, 0], [1.0, 0, 0]])
    t = box.intersect(o, d)
    assert not np.any(np.isnan(t))
    np.testing.assert_allclose(t[:3], [4.0 - 0.25, 2.0, 3.0 - 0.5], atol=1e-5)
    assert np.isinf(t[3])          # passes beside the box (|dy| = 0.6 > 0.5)
    assert np.isinf(t[4])          # origin inside: objects are only seen from outside
    p = o[:, :3] + t[:3] * d[:, :3]
    n, pid, u, v = box.surface(p)
    np.testing.assert_allclose(n.T, [[-1, 0, 0], [0, 0, 1], [0, 1, 0]], atol=1e-6)
    assert np.all((u >= 0) & (u <= 1) & (v >= 0) & (v <= 1))


@pytest.mark.parametrize("make", [
    lambda: geo.Sphere(centre=[0.2, -0.1, 0.4], radius=0.4, yaw=0.3, patch=0),
    lambda: geo.Cylinder(centre_xy=[0.3, 0.2], base_z=0.0, radius=0.25, height=0.8, yaw=1.0,
                         side_patch=0, top_patch=1),
    lambda: geo.Box(centre=[0.0, 0.1, 0.3], half=[0.3, 0.2, 0.3], yaw=0.4, patches=tuple(range(6))),
])
def test_object_surface_samples_are_hit_by_rays_from_outside(make):
    """Points sampled on a surface are where rays towards them from outside first
    hit it (the sampled side is visible), with outward unit normals."""
    obj = make()
    rng = np.random.default_rng(1)
    pts = obj.sample(400, rng)
    n, pid, u, v = obj.surface(soa(pts))
    np.testing.assert_allclose(np.linalg.norm(n, axis=0), 1, atol=1e-5)
    assert np.all((u >= -1e-6) & (u <= 1 + 1e-6) & (v >= -1e-6) & (v <= 1 + 1e-6))
    # start 2 units out along the normal and shoot back
    start = pts + 2.0 * n.T
    d = -n.T
    t = obj.intersect(soa(start), soa(d))
    np.testing.assert_allclose(t, 2.0, atol=2e-4)


def test_environment_encloses_the_orbit():
    """Every ray from a camera position hits the ground, wall or ceiling."""
    world = build_world(0, *wall_size(3.0))
    rng = np.random.default_rng(0)
    d = rng.normal(size=(5000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for c in orbit_c2w(5, 3.0, 25.0, 8.0)[:, :3, 3]:
        o = np.broadcast_to(soa(c), (3, len(d)))
        t, idx = cast(world, o, soa(d))
        assert np.all(np.isfinite(t)) and np.all(idx >= 0)


# ----------------------------------------------------------------------------- cameras

def test_orbit_cameras_look_at_target_and_are_not_coplanar():
    c2w = orbit_c2w(36, 3.0, 25.0, 8.0)
    fx, fy, cx, cy = intrinsics(320, 240, 50.0)
    K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])
    for T in c2w:
        check_pose(T)
        x = K @ (T[:3, :3].T @ (TARGET - T[:3, 3]))
        np.testing.assert_allclose(x[:2] / x[2], [cx, cy], atol=1e-9)
        assert T[2, 1] < 0  # image 'down' points down in the world (no roll, upright)
    C = c2w[:, :3, 3]
    np.testing.assert_allclose(np.linalg.norm(C - TARGET, axis=1), 3.0)
    el = np.degrees(np.arcsin((C[:, 2] - TARGET[2]) / 3.0))
    assert el.min() == pytest.approx(17.0, abs=0.3) and el.max() == pytest.approx(33.0, abs=0.3)
    s = np.linalg.svd(C - C.mean(0), compute_uv=False)
    assert s[2] / s[0] > 0.05  # a genuinely 3D set of centres
    # consecutive views 10 deg apart in azimuth
    ang = np.degrees(geodesic_angle(c2w[:-1, :3, :3], c2w[1:, :3, :3]))
    assert np.all((ang > 9) & (ang < 13))


def test_camera_rays_pass_through_pixel_centres():
    c2w = orbit_c2w(4, 3.0, 25.0, 8.0)[1]
    fx, fy, cx, cy = intrinsics(40, 30, 60.0)
    origin, d = camera_rays(c2w, fx, fy, cx, cy, 40, 30, supersample=1)
    X = origin[:, None] + 2.5 * d  # points along the rays, world frame
    Xc = c2w[:3, :3].T @ (X - c2w[:3, 3:4])
    u = fx * Xc[0] / Xc[2] + cx
    v = fy * Xc[1] / Xc[2] + cy
    jj, ii = np.meshgrid(np.arange(40), np.arange(30))
    np.testing.assert_allclose(u, jj.ravel() + 0.5, atol=1e-4)
    np.testing.assert_allclose(v, ii.ravel() + 0.5, atol=1e-4)
    # supersampling 2: four sub-samples per pixel at +0.25 / +0.75
    _, d2 = camera_rays(c2w, fx, fy, cx, cy, 40, 30, supersample=2)
    Xc2 = c2w[:3, :3].T @ d2
    u2 = (fx * Xc2[0] / Xc2[2] + cx).reshape(60, 80)
    np.testing.assert_allclose(u2[0, :4], [0.25, 0.75, 1.25, 1.75], atol=1e-4)


# ----------------------------------------------------------------------------- the scene on disk

@pytest.fixture(scope="module")
def small_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo") / "scene"
    stats = generate_demo_scene(out, cfg())
    return out, stats


def test_scene_layout(small_scene):
    out, stats = small_scene
    scene = read_scene(out)
    assert scene.layout == "demo" and scene.has_poses
    assert (scene.width, scene.height) == (96, 72)
    assert [f.name for f in scene.frames] == [f"{k:03d}.png" for k in range(8)]
    fx, fy, cx, cy = intrinsics(96, 72, 50.0)
    for f in scene.frames:
        assert f.camera.model == "PINHOLE" and f.camera.dist == []
        assert (f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy) == (fx, fy, cx, cy)
        img = np.asarray(Image.open(out / "images" / f.name))
        assert img.shape == (72, 96, 3) and img.dtype == np.uint8
        assert img.std() > 25  # textured everywhere, not a flat render
    np.testing.assert_allclose(scene.c2w_array(), orbit_c2w(8, 3.0, 25.0, 8.0))
    assert scene.points_xyz.shape[1] == 3 and 1500 < len(scene.points_xyz) <= 2000
    assert scene.points_rgb.dtype == np.uint8 and np.all(np.isfinite(scene.points_xyz))
    assert stats["n_views"] == 8 and stats["seconds"] > 0
    assert not list(out.parent.glob(".*tmp*"))  # no temporary left over


def test_same_config_gives_identical_bytes(small_scene, tmp_path):
    out, _ = small_scene
    again = tmp_path / "again"
    generate_demo_scene(again, cfg())
    for f in sorted((out / "images").iterdir()):
        assert (again / "images" / f.name).read_bytes() == f.read_bytes(), f.name
    assert (again / "scene.json").read_bytes() == (out / "scene.json").read_bytes()
    with np.load(out / "points3d.npz") as a, np.load(again / "points3d.npz") as b:
        assert np.array_equal(a["xyz"], b["xyz"]) and np.array_equal(a["rgb"], b["rgb"])
    other = tmp_path / "seed1"
    generate_demo_scene(other, cfg(seed=1))
    assert (other / "images" / "000.png").read_bytes() != (out / "images" / "000.png").read_bytes()


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Image (H, W, 3) sampled at continuous array coordinates x, y (pixel i at i)."""
    x0 = np.floor(x).astype(int)
    y0 = np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    g = lambda yy, xx: img[yy, xx].astype(np.float64)  # noqa: E731
    return ((g(y0, x0) * (1 - fx) + g(y0, x0 + 1) * fx) * (1 - fy)
            + (g(y0 + 1, x0) * (1 - fx) + g(y0 + 1, x0 + 1) * fx) * fy)


def test_points_project_onto_pixels_of_their_colour(tmp_path):
    """Project the surface points with the ground-truth cameras of two views: the
    image colour there matches the point colour, and it matches clearly worse if
    the pixel-centre convention or the pose were off by half a pixel or more."""
    out = tmp_path / "scene"
    c = cfg(n_views=12, width=320, height=240, supersample=1, n_points=6000)
    generate_demo_scene(out, c)
    scene = read_scene(out)
    world = build_world(c.seed, *wall_size(c.orbit_radius))
    X = scene.points_xyz
    rgb = scene.points_rgb.astype(np.float64)
    for k in (0, 7):
        f = scene.frames[k]
        img = np.asarray(Image.open(out / "images" / f.name))
        R, C = f.c2w[:3, :3], f.c2w[:3, 3]
        Xc = (X - C) @ R
        z = Xc[:, 2]
        u = f.camera.fx * Xc[:, 0] / z + f.camera.cx
        v = f.camera.fy * Xc[:, 1] / z + f.camera.cy
        inside = (z > 0.1) & (u > 3) & (u < scene.width - 3) & (v > 3) & (v < scene.height - 3)
        # visibility: the first surface along the ray from the camera is the point itself
        dist = np.linalg.norm(X - C, axis=1)
        t, _ = cast(world, np.broadcast_to(soa(C), (3, len(X))), soa((X - C) / dist[:, None]))
        vis = inside & (np.abs(t - dist) < 1e-3 * dist + 1e-3)
        assert vis.sum() > 1000, f"view {k}: only {vis.sum()} visible points"
        uu, vv, col = u[vis], v[vis], rgb[vis]

        def err(du: float, dv: float) -> float:
            # pixel centres at +0.5: continuous (u, v) is array position (u - 0.5, v - 0.5)
            return float(np.median(np.abs(_bilinear(img, uu - 0.5 + du, vv - 0.5 + dv) - col).mean(1)))

        e0 = err(0, 0)
        assert e0 < 5.0, f"view {k}: median colour error {e0:.2f} / 255"
        assert e0 < 0.75 * err(0.5, 0.5)   # integer pixel centres would be worse
        assert e0 < 0.6 * err(1.0, 0.0)
        assert e0 < 0.6 * err(0.0, -1.0)


# ----------------------------------------------------------------------------- errors

@pytest.mark.parametrize("over, key", [
    ({"orbit_elevation_deg": -20.0}, "demo.orbit_elevation_deg"),
    ({"orbit_elevation_deg": 60.0, "elevation_wobble_deg": 30.0}, "demo.elevation_wobble_deg"),
    ({"orbit_radius": 0.5}, "demo.orbit_radius"),
])
def test_impossible_orbits_are_rejected(over, key):
    with pytest.raises(ConfigError, match=key):
        check_orbit(cfg(**over))


def test_cli_bad_config_exits_2_and_leaves_no_output(tmp_path, capsys):
    out = tmp_path / "scene"
    assert gs2e_main(["demo-scene", "--out", str(out), "--config-json", '{"n_viewz": 8}']) == 2
    assert "demo.n_viewz" in capsys.readouterr().err
    assert gs2e_main(["demo-scene", "--out", str(out),
                      "--config-json", '{"n_views": 8, "orbit_elevation_deg": -30}']) == 2
    assert "demo.orbit_elevation_deg" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_cli_writes_scene_and_replaces_existing(tmp_path):
    out = tmp_path / "scene"
    out.mkdir()
    (out / "stale.txt").write_text("old")
    conf = tmp_path / "config.yaml"
    conf.write_text("demo:\n  n_views: 8\n  width: 64\n  height: 48\n  n_points: 500\n")
    assert gs2e_main(["demo-scene", "--out", str(out), "--config", str(conf)]) == 0
    assert not (out / "stale.txt").exists()
    scene = read_scene(out)
    assert len(scene.frames) == 8 and scene.width == 64
    assert sorted(p.name for p in tmp_path.iterdir()) == ["config.yaml", "scene"]


def test_chunking_does_not_change_the_image():
    world = build_world(3, *wall_size(3.0))
    c2w = orbit_c2w(8, 3.0, 25.0, 8.0)[5]
    fx, fy, cx, cy = intrinsics(80, 60, 50.0)
    a = render_view(world, c2w, fx, fy, cx, cy, 80, 60, 2, chunk=80 * 60 * 4)
    b = render_view(world, c2w, fx, fy, cx, cy, 80, 60, 2, chunk=997)
    assert a.shape == (60, 80, 3) and np.array_equal(a, b)


def test_every_demo_key_has_a_default_and_a_description():
    from gs2e.config import load_schema

    props = load_schema()["properties"]["demo"]["properties"]
    assert all("default" in v and v.get("description") for v in props.values())
