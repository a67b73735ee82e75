"""The demo world (objects on a textured ground inside a textured wall), the
orbit of cameras around it, and the ray caster / shader that renders it.

Shading is static and view-independent (3DGS needs a static scene): colour =
albedo * (AMBIENT + DIFFUSE * max(0, n . L) * unshadowed) for objects and the
ground, with a fixed directional light L and hard shadows cast by the objects;
the wall and ceiling are unlit (albedo * BACKDROP_GAIN), like a printed
panorama. The same function colours rendered pixels and the sampled surface
points of ``points3d.npz``, so a point's colour is what a camera sees there.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from gs2e.common.errors import ConfigError
from gs2e.demo.geometry import F32, Box, Ceiling, Cylinder, Ground, Sphere, Wall
from gs2e.demo.settings import DemoSettings
from gs2e.demo.textures import COLOUR_PHOTOS, GREY_PHOTOS, Atlas, build_atlas

LIGHT_DIR = np.array([0.45, 0.3, 1.0], F32) / np.float32(np.linalg.norm([0.45, 0.3, 1.0]))
AMBIENT = 0.42
DIFFUSE = 0.62
BACKDROP_GAIN = 0.95
TARGET = np.array([0.0, 0.0, 0.35])  # object centre the cameras look at (scene units)
WOBBLE_PERIODS = 3  # elevation oscillations per orbit (not 1: a tilted circle would be planar)
TEXTURE_SIZE = 256  # texels per atlas texture side
RAY_CHUNK = 1 << 15  # rays per batch in render_view

OBJECT_POOL = ("astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry")
GROUND_POOL = ("gravel", "grass", "brick")
WALL_POOL = ("astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry",
             "camera", "coins", "moon", "page", "text", "brick", "gravel")


@dataclass
class World:
    """Primitives (objects first, then ground, wall, ceiling) and their textures."""

    atlas: Atlas
    objects: list
    env: list
    bound_centre: np.ndarray = field(init=False)
    bound_radius: float = field(init=False)

    def __post_init__(self) -> None:
        cs = np.array([o.centre for o in self.objects], np.float64)
        self.bound_centre = cs.mean(axis=0).astype(F32)
        self.bound_radius = float(max(np.linalg.norm(c - self.bound_centre) + o.bound_radius
                                      for c, o in zip(cs, self.objects))) * 1.001

    @property
    def prims(self) -> list:
        return self.objects + self.env


def build_world(seed: int, wall_radius: float, wall_height: float) -> World:
    """Four textured objects around the origin on a tiled ground inside a wall.

    Object sizes and places are jittered and photos/crops chosen by ``seed``;
    all lengths are scene units (the objects span about 2 units).
    """
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7]))
    atlas = build_atlas(COLOUR_PHOTOS + GREY_PHOTOS, TEXTURE_SIZE)

    def jit(scale: float, n: int = 1) -> np.ndarray:
        return rng.uniform(-scale, scale, n)

    def obj_patch(win: float = 150.0) -> int:
        return atlas.random_patch(rng, OBJECT_POOL, (win, win))

    objects: list = []
    hz = 0.34 + jit(0.03)[0]
    objects.append(Box(centre=[-0.38 + jit(0.04)[0], -0.15 + jit(0.04)[0], hz],
                       half=[0.34, 0.27, hz], yaw=math.radians(20 + jit(15)[0]),
                       patches=tuple(obj_patch() for _ in range(6))))
    hz = 0.19 + jit(0.02)[0]
    objects.append(Box(centre=[-0.12 + jit(0.04)[0], 0.62 + jit(0.04)[0], hz],
                       half=[0.2, 0.19, hz], yaw=math.radians(45 + jit(30)[0]),
                       patches=tuple(obj_patch(110) for _ in range(6))))
    r = 0.32 + jit(0.02)[0]
    objects.append(Sphere(centre=[0.5 + jit(0.03)[0], 0.3 + jit(0.03)[0], r], radius=r,
                          yaw=float(rng.uniform(0, 2 * np.pi)),
                          patch=atlas.random_patch(rng, OBJECT_POOL, (256, 220))))
    objects.append(Cylinder(centre_xy=[0.38 + jit(0.03)[0], -0.6 + jit(0.03)[0]], base_z=0.0,
                            radius=0.21, height=0.9 + jit(0.08)[0],
                            yaw=float(rng.uniform(0, 2 * np.pi)),
                            side_patch=atlas.random_patch(rng, OBJECT_POOL, (256, 170)),
                            top_patch=obj_patch(90)))

    tile = 1.0
    n_tiles = int(math.ceil(2 * wall_radius / tile)) + 2
    ground_grid = np.array([atlas.random_patch(rng, GROUND_POOL, (128, 128), rotate=True)
                            for _ in range(n_tiles * n_tiles)], np.int64).reshape(n_tiles, n_tiles)
    ground = Ground(tile=tile, patch_grid=ground_grid, radius=wall_radius)

    n_rows = 2
    n_secs = max(8, int(round(2 * math.pi * wall_radius / 3.5)))
    panel_w = 2 * math.pi * wall_radius / n_secs
    panel_h = wall_height / n_rows
    win_w = 240.0
    win_h = min(256.0, win_w * panel_h / panel_w)  # keep the photos' aspect on the panels
    wall_grid = np.array([atlas.random_patch(rng, WALL_POOL, (win_w, win_h))
                          for _ in range(n_rows * n_secs)], np.int64).reshape(n_rows, n_secs)
    wall = Wall(radius=wall_radius, height=wall_height, patch_grid=wall_grid)
    ceiling = Ceiling(radius=wall_radius, height=wall_height,
                      patch=atlas.add_patch("hubble_deep_field"))
    return World(atlas=atlas, objects=objects, env=[ground, wall, ceiling])


# --------------------------------------------------------------------------- cameras

def look_at_c2w(centre: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Camera-to-world (4, 4) float64 of a camera at ``centre`` looking at ``target``,
    OpenCV axes (x right, y down, z forward), world up +z, no roll."""
    f = np.asarray(target, np.float64) - np.asarray(centre, np.float64)
    f /= np.linalg.norm(f)
    right = np.cross(f, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(f, right)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = right, down, f, centre
    return T


def orbit_c2w(n_views: int, radius: float, elevation_deg: float, wobble_deg: float,
              target: np.ndarray = TARGET) -> np.ndarray:
    """(n_views, 4, 4) camera-to-world poses on an orbit around ``target``.

    View k sits at azimuth 2 pi k / n_views, elevation elevation_deg +
    wobble_deg * sin(WOBBLE_PERIODS * azimuth), ``radius`` units from the target.
    """
    az = 2 * np.pi * np.arange(n_views) / n_views
    el = np.radians(elevation_deg + wobble_deg * np.sin(WOBBLE_PERIODS * az))
    C = np.asarray(target, np.float64) + radius * np.stack(
        [np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    return np.stack([look_at_c2w(c, target) for c in C])


def intrinsics(width: int, height: int, fov_deg: float) -> tuple[float, float, float, float]:
    """Pinhole (fx, fy, cx, cy) in pixels for a horizontal field of view; square pixels,
    principal point at the image centre (pixel centres at integer + 0.5)."""
    fx = (width / 2) / math.tan(math.radians(fov_deg) / 2)
    return fx, fx, width / 2, height / 2


def check_orbit(cfg: DemoSettings) -> None:
    """Reject orbits whose cameras leave the world (below the ground, outside the wall)
    or look straight down (look-at with world-up is undefined there)."""
    el_max = abs(cfg.orbit_elevation_deg) + cfg.elevation_wobble_deg
    if el_max >= 85:
        raise ConfigError(f"demo.elevation_wobble_deg: |orbit_elevation_deg| + elevation_wobble_deg "
                          f"= {el_max:g} deg must be below 85 deg")
    z_min = TARGET[2] + cfg.orbit_radius * math.sin(
        math.radians(cfg.orbit_elevation_deg - cfg.elevation_wobble_deg))
    if z_min < 0.05:
        raise ConfigError(f"demo.orbit_elevation_deg: the lowest camera would be at height {z_min:.3f}, "
                          f"below the ground plane; raise orbit_elevation_deg or lower elevation_wobble_deg")
    if cfg.orbit_radius < 1.2:
        raise ConfigError(f"demo.orbit_radius: {cfg.orbit_radius:g} units puts cameras inside the objects "
                          f"(need >= 1.2)")


def wall_size(orbit_radius: float) -> tuple[float, float]:
    """Wall radius and height (scene units) enclosing an orbit of ``orbit_radius``."""
    radius = max(6.0, 2.0 * orbit_radius)
    return radius, max(0.75 * radius, TARGET[2] + orbit_radius + 1.0)


# --------------------------------------------------------------------------- ray casting

def _ray_hits_sphere(o: np.ndarray, d: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
    ox, oy, oz = o[0] - c[0], o[1] - c[1], o[2] - c[2]
    b = ox * d[0] + oy * d[1] + oz * d[2]
    cc = ox * ox + oy * oy + oz * oz - F32(r * r)
    return (b * b - cc >= 0) & ((b < 0) | (cc < 0))


def cast(world: World, o: np.ndarray, d: np.ndarray, objects_only: bool = False):
    """Closest hit of rays: origins o (3, N) and unit directions d (3, N), float32
    (one row per axis; o may be a broadcast single origin).

    Returns t (N,) float32 (+inf for a miss) and the primitive index (N,) int8
    into ``world.prims`` (-1 for a miss). Objects are tested only for rays that
    meet their bounding sphere.
    """
    n = d.shape[1]
    t = np.full(n, np.inf, F32)
    idx = np.full(n, -1, np.int8)
    sel = np.flatnonzero(_ray_hits_sphere(o, d, world.bound_centre, world.bound_radius))
    if len(sel):
        os_, ds = np.ascontiguousarray(o[:, sel]), np.ascontiguousarray(d[:, sel])
        ts = np.full(len(sel), np.inf, F32)
        ids = np.full(len(sel), -1, np.int8)
        for i, prim in enumerate(world.objects):
            ti = prim.intersect(os_, ds)
            better = ti < ts
            ts = np.where(better, ti, ts)
            ids[better] = i
        t[sel] = ts
        idx[sel] = ids
    if not objects_only:
        for j, prim in enumerate(world.env, start=len(world.objects)):
            ti = prim.intersect(o, d)
            better = ti < t
            t = np.where(better, ti, t)
            idx[better] = j
    return t, idx


def shade(world: World, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """Static colour (3, N) float32 in [0, 1] of surface points p (3, N) lying on
    primitives ``idx`` (N,) (index into world.prims; -1 gives black)."""
    p = np.asarray(p, F32)
    n_pts = p.shape[1]
    albedo = np.zeros((3, n_pts), F32)
    normal = np.zeros((3, n_pts), F32)
    lit = np.zeros(n_pts, bool)
    # one stable (radix, for int8) sort instead of a mask per primitive
    key = np.asarray(idx).astype(np.int8)
    order = np.argsort(key, kind="stable")
    bounds = np.searchsorted(key[order], np.arange(len(world.prims) + 1, dtype=np.int8))
    for i, prim in enumerate(world.prims):
        m = order[bounds[i]:bounds[i + 1]]
        if not len(m):
            continue
        nrm, pid, u, v = prim.surface(p[:, m])
        albedo[:, m] = world.atlas.lookup(pid, u, v)
        normal[:, m] = nrm
        lit[m] = prim.lit
    gain = np.full(n_pts, BACKDROP_GAIN, F32)
    li = np.flatnonzero(lit)
    if len(li):
        nl = normal[:, li]
        cos = np.maximum(nl[0] * LIGHT_DIR[0] + nl[1] * LIGHT_DIR[1] + nl[2] * LIGHT_DIR[2], 0)
        facing = np.flatnonzero(cos > 0)
        if len(facing):
            pts = li[facing]
            o = p[:, pts] + F32(1e-3) * normal[:, pts]
            d = np.broadcast_to(LIGHT_DIR[:, None], o.shape)
            t_sh, _ = cast(world, o, d, objects_only=True)
            cos[facing[np.isfinite(t_sh)]] = 0
        gain[li] = AMBIENT + DIFFUSE * cos
    gain[idx < 0] = 0
    return np.minimum(albedo * gain, 1)


def camera_rays(c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                width: int, height: int, supersample: int = 1, rows: tuple[int, int] | None = None):
    """Rays through sub-pixel sample points, row-major over (height*ss, width*ss).

    Pixel (i, j) covers [j, j+1) x [i, i+1); its ss x ss samples sit at
    j + (a + 0.5)/ss, so with ss = 1 the ray passes through the pixel centre
    (j + 0.5, i + 0.5). ``rows`` = (first, stop) restricts to those sample rows.
    Returns origin (3,) float32 and unit directions (3, M) float32.
    """
    ss = int(supersample)
    off = (np.arange(ss) + 0.5) / ss
    xs = (np.arange(width)[:, None] + off[None, :]).reshape(-1)
    ys = (np.arange(height)[:, None] + off[None, :]).reshape(-1)
    if rows is not None:
        ys = ys[rows[0]:rows[1]]
    dx = ((xs - cx) / fx).astype(F32)
    dy = ((ys - cy) / fy).astype(F32)
    R = np.asarray(c2w, np.float64)[:3, :3].astype(F32)
    # d_world = R @ [dx, dy, 1] for every (row, column) sample
    d = (R[:, 0, None, None] * dx[None, None, :] + R[:, 1, None, None] * dy[None, :, None]
         + R[:, 2, None, None]).reshape(3, -1)
    d /= np.sqrt((d * d).sum(axis=0))
    return np.asarray(c2w, np.float64)[:3, 3].astype(F32), d


def render_view(world: World, c2w: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                width: int, height: int, supersample: int = 2, chunk: int = RAY_CHUNK) -> np.ndarray:
    """Render one view: (height, width, 3) uint8 RGB, box-filtered over ss x ss samples.

    Rays are made and cast about ``chunk`` at a time, whole pixel rows per batch,
    so memory stays bounded at any resolution (the image does not depend on it).
    """
    ss = int(supersample)
    img = np.empty((3, height, width), F32)
    pix_rows = max(1, int(chunk) // (width * ss * ss))
    for r0 in range(0, height, pix_rows):  # small batches keep the temporaries in cache
        r1 = min(height, r0 + pix_rows)
        origin, d = camera_rays(c2w, fx, fy, cx, cy, width, height, ss, rows=(r0 * ss, r1 * ss))
        o = np.broadcast_to(origin[:, None], d.shape)
        t, idx = cast(world, o, d)
        rgb = shade(world, o + np.where(idx >= 0, t, 0) * d, idx)
        img[:, r0:r1] = rgb.reshape(3, r1 - r0, ss, width, ss).sum(axis=(2, 4))
    img *= F32(255.0 / (ss * ss))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8).transpose(1, 2, 0).copy()


def sample_points(world: World, n_points: int, rng: np.random.Generator):
    """Surface points and their static colours, an SfM-like point cloud.

    About 55% of the points go to the objects (by area), 25% to the ground,
    20% to the wall and ceiling; points hidden inside objects (ground under a
    box) are dropped. Returns xyz (P, 3) float64 and rgb (P, 3) uint8.
    """
    n_obj = int(round(0.55 * n_points))
    areas = np.array([_area(o) for o in world.objects])
    counts = np.floor(n_obj * areas / areas.sum()).astype(int)
    ground, wall, ceiling = world.env
    wall_share = wall.height * 2 * np.pi * wall.radius
    ceil_share = np.pi * wall.radius ** 2 * 0.1  # rarely seen: few points
    n_env = n_points - counts.sum()
    n_ground = int(round(0.25 / 0.45 * n_env))
    n_wall = int(round((n_env - n_ground) * wall_share / (wall_share + ceil_share)))
    n_ceil = n_env - n_ground - n_wall
    xyz, idx = [], []
    for i, (prim, k) in enumerate(zip(world.prims, [*counts, n_ground, n_wall, n_ceil])):
        pts = prim.sample(int(k), rng)
        xyz.append(pts)
        idx.append(np.full(len(pts), i, np.int64))
    xyz = np.concatenate(xyz)
    idx = np.concatenate(idx)
    # drop points buried in another object (ground under a box, ...); the probe is
    # lifted off the ground so a point on z = 0 under a box counts as inside it
    probe = np.ascontiguousarray(xyz.T, F32)
    probe[2] += F32(1e-3)
    buried = np.zeros(len(xyz), bool)
    for i, obj in enumerate(world.objects):
        buried |= (idx != i) & obj.contains(probe)
    xyz, idx = xyz[~buried], idx[~buried]
    rgb = shade(world, np.ascontiguousarray(xyz.T, F32), idx).T
    return xyz.astype(np.float64), np.clip(np.rint(rgb * 255), 0, 255).astype(np.uint8)


def _area(obj) -> float:
    if isinstance(obj, Box):
        h = obj.half.astype(np.float64)
        return 4 * (h[0] * h[1] + 2 * h[0] * h[2] + 2 * h[1] * h[2])
    if isinstance(obj, Sphere):
        return 4 * np.pi * obj.radius ** 2
    if isinstance(obj, Cylinder):
        return 2 * np.pi * obj.radius * obj.height + np.pi * obj.radius ** 2
    raise TypeError(type(obj).__name__)
