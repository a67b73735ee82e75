"""Analytic ray-primitive intersections for the demo world (vectorised numpy).

World frame: right-handed, +z up, ground plane z = 0, units = scene units.
Arrays are structure-of-arrays (one contiguous row per axis), which numpy
handles several times faster than (N, 3): ray origins ``o`` (3, N) and unit
directions ``d`` (3, N), float32. Every ``intersect`` returns the ray parameter
t (N,) of the first hit in front of the origin (t > EPS_T), +inf where the ray
misses. Every ``surface`` maps hit points p (3, N) to outward unit normals
(3, N), a patch id (N,) and patch coordinates u, v (N,) in [0, 1] (u right,
v down the photo) for :meth:`Atlas.lookup`. ``sample`` draws points (P, 3)
float64 uniformly (by area) on the visible surface; ``contains`` takes (3, N).

Objects (Box, Sphere, Cylinder) stand on the ground and are seen from outside;
the environment (Ground, Wall, Ceiling) encloses the cameras and is seen from
inside, so every camera ray hits something.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EPS_T = 1e-4  # minimum hit distance (scene units): avoids self-hits of shadow rays
F32 = np.float32
INF = F32(np.inf)


def _yaw_matrix(yaw_rad: float) -> np.ndarray:
    """Local-to-world rotation about +z, (3, 3) float64."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _safe_inv(x: np.ndarray) -> np.ndarray:
    """1/x with exact zeros nudged so slab tests never produce 0*inf = NaN."""
    return F32(1.0) / np.where(x == 0, F32(1e-20), x)


class _Yawed:
    """Mixin: world <-> local frame of an object turned by ``yaw`` about +z."""

    def _set_frame(self, yaw: float) -> None:
        self.R = _yaw_matrix(yaw)
        self._c, self._s = F32(np.cos(yaw)), F32(np.sin(yaw))

    def to_local(self, x: np.ndarray, y: np.ndarray, z: np.ndarray):
        """Local coordinates of world vectors (x, y, z rows), q = R^T v."""
        return self._c * x + self._s * y, self._c * y - self._s * x, z

    def to_world(self, x: np.ndarray, y: np.ndarray, z: np.ndarray):
        return self._c * x - self._s * y, self._s * x + self._c * y, z


# Box faces: (axis, sign) of the outward normal, then the local axis/sign that
# runs along the photo's u (rightwards for a viewer facing the face, up = +z)
# and along its v (downwards).
_BOX_FACES = (
    # axis sign  ua us  va vs
    (0, +1, 1, +1, 2, -1),
    (0, -1, 1, -1, 2, -1),
    (1, +1, 0, -1, 2, -1),
    (1, -1, 0, +1, 2, -1),
    (2, +1, 0, +1, 1, -1),
    (2, -1, 0, +1, 1, +1),
)
_FACE_TABLE = np.array(_BOX_FACES, np.int64)


@dataclass
class Box(_Yawed):
    """Box with centre (3,), half extents (3,) and a yaw about +z (rad);
    ``patches`` holds one patch id per face in the order +x, -x, +y, -y, +z, -z."""

    centre: np.ndarray
    half: np.ndarray
    yaw: float
    patches: tuple[int, ...]
    lit: bool = True

    def __post_init__(self) -> None:
        self.centre = np.asarray(self.centre, F32)
        self.half = np.asarray(self.half, F32)
        self._set_frame(self.yaw)
        self.patches_arr = np.asarray(self.patches, np.int64)

    @property
    def bound_radius(self) -> float:
        return float(np.linalg.norm(self.half))

    def local(self, p: np.ndarray):
        return self.to_local(p[0] - self.centre[0], p[1] - self.centre[1], p[2] - self.centre[2])

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        lo = self.local(o)
        ld = self.to_local(d[0], d[1], d[2])
        tmin = tmax = None
        for a in range(3):  # slab test, one axis at a time on contiguous rows
            inv = _safe_inv(ld[a])
            t1 = (-self.half[a] - lo[a]) * inv
            t2 = (self.half[a] - lo[a]) * inv
            lo_t, hi_t = np.minimum(t1, t2), np.maximum(t1, t2)
            tmin = lo_t if tmin is None else np.maximum(tmin, lo_t)
            tmax = hi_t if tmax is None else np.minimum(tmax, hi_t)
        return np.where((tmax >= tmin) & (tmin > EPS_T), tmin, INF)

    def contains(self, p: np.ndarray) -> np.ndarray:
        q = self.local(p)
        return (np.abs(q[0]) <= self.half[0]) & (np.abs(q[1]) <= self.half[1]) & (np.abs(q[2]) <= self.half[2])

    def surface(self, p: np.ndarray):
        q = np.stack(self.local(p))
        rel = np.abs(q) / self.half[:, None]
        axis = rel.argmax(axis=0)
        cols = np.arange(p.shape[1])
        sign = q[axis, cols] >= 0
        face = axis * 2 + (~sign)
        ft = _FACE_TABLE[face]
        nl = np.zeros_like(q)
        nl[ft[:, 0], cols] = ft[:, 1]
        n = np.stack(self.to_world(nl[0], nl[1], nl[2]))
        hu = self.half[ft[:, 2]]
        hv = self.half[ft[:, 4]]
        u = (ft[:, 3] * q[ft[:, 2], cols] + hu) / (2 * hu)
        v = (ft[:, 5] * q[ft[:, 4], cols] + hv) / (2 * hv)
        return n.astype(F32), self.patches_arr[face], u, v

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """Points on the five faces other than the bottom (which rests on the ground)."""
        h = self.half.astype(np.float64)
        areas = np.array([4 * h[(a + 1) % 3] * h[(a + 2) % 3] for a, *_ in _BOX_FACES[:5]])
        face = rng.choice(5, size=n, p=areas / areas.sum())
        q = rng.uniform(-1, 1, (n, 3)) * h
        ax = _FACE_TABLE[face, 0]
        q[np.arange(n), ax] = _FACE_TABLE[face, 1] * h[ax]
        return q @ self.R.T + self.centre.astype(np.float64)


@dataclass
class Sphere(_Yawed):
    """Sphere (centre (3,), radius); the photo wraps in longitude/latitude about
    an axis turned by ``yaw``."""

    centre: np.ndarray
    radius: float
    yaw: float
    patch: int
    lit: bool = True

    def __post_init__(self) -> None:
        self.centre = np.asarray(self.centre, F32)
        self._set_frame(self.yaw)

    @property
    def bound_radius(self) -> float:
        return float(self.radius)

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        ox, oy, oz = o[0] - self.centre[0], o[1] - self.centre[1], o[2] - self.centre[2]
        b = ox * d[0] + oy * d[1] + oz * d[2]
        c = ox * ox + oy * oy + oz * oz - F32(self.radius ** 2)
        disc = b * b - c
        t = -b - np.sqrt(np.maximum(disc, 0))
        return np.where((disc >= 0) & (t > EPS_T), t, INF)

    def contains(self, p: np.ndarray) -> np.ndarray:
        return ((p[0] - self.centre[0]) ** 2 + (p[1] - self.centre[1]) ** 2
                + (p[2] - self.centre[2]) ** 2) <= F32(self.radius ** 2)

    def surface(self, p: np.ndarray):
        n = p - self.centre[:, None]
        n = n / np.sqrt((n * n).sum(axis=0))
        qx, qy, qz = self.to_local(n[0], n[1], n[2])
        u = np.arctan2(qy, qx) / F32(2 * np.pi) + F32(0.5)
        v = np.arccos(np.clip(qz, -1, 1)) / F32(np.pi)
        return n.astype(F32), np.full(p.shape[1], self.patch, np.int64), u, v

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        g = rng.normal(size=(n, 3))
        g /= np.linalg.norm(g, axis=1, keepdims=True)
        return self.centre.astype(np.float64) + self.radius * g


@dataclass
class Cylinder(_Yawed):
    """Upright cylinder standing on z = base_z: side and top cap textured."""

    centre_xy: np.ndarray
    base_z: float
    radius: float
    height: float
    yaw: float
    side_patch: int
    top_patch: int
    lit: bool = True

    def __post_init__(self) -> None:
        self.centre_xy = np.asarray(self.centre_xy, F32)
        self._set_frame(self.yaw)
        self.centre = np.array([*self.centre_xy, self.base_z + self.height / 2], F32)

    @property
    def bound_radius(self) -> float:
        return float(np.hypot(self.radius, self.height / 2))

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        ox = o[0] - self.centre_xy[0]
        oy = o[1] - self.centre_xy[1]
        a = d[0] * d[0] + d[1] * d[1]
        b = ox * d[0] + oy * d[1]
        c = ox * ox + oy * oy - F32(self.radius ** 2)
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            ts = (-b - np.sqrt(np.maximum(disc, 0))) / a
            z = o[2] + ts * d[2]
            top = F32(self.base_z + self.height)
            side_ok = (disc >= 0) & (a > 1e-12) & (ts > EPS_T) & (z >= self.base_z) & (z <= top)
            t = np.where(side_ok, ts, INF)
            tc = (top - o[2]) / d[2]
            cx = ox + tc * d[0]
            cy = oy + tc * d[1]
            cap_ok = (d[2] < 0) & (tc > EPS_T) & (cx * cx + cy * cy <= F32(self.radius ** 2))
        return np.where(cap_ok & (tc < t), tc, t)

    def contains(self, p: np.ndarray) -> np.ndarray:
        r2 = (p[0] - self.centre_xy[0]) ** 2 + (p[1] - self.centre_xy[1]) ** 2
        return (r2 <= self.radius ** 2) & (p[2] >= self.base_z) & (p[2] <= self.base_z + self.height)

    def surface(self, p: np.ndarray):
        qx, qy, qz = self.to_local(p[0] - self.centre[0], p[1] - self.centre[1], p[2] - self.centre[2])
        rad = np.hypot(qx, qy)
        on_cap = (self.height / 2 - qz) < (self.radius - rad)
        r_safe = np.maximum(rad, F32(1e-12))
        nx, ny, _ = self.to_world(qx / r_safe, qy / r_safe, 0)
        n = np.stack([np.where(on_cap, 0, nx), np.where(on_cap, 0, ny),
                      on_cap.astype(F32)]).astype(F32)
        u_side = np.arctan2(qy, qx) / F32(2 * np.pi) + F32(0.5)
        v_side = (self.height / 2 - qz) / F32(self.height)
        u_cap = (qx / self.radius + 1) / 2
        v_cap = (1 - qy / self.radius) / 2
        u = np.where(on_cap, u_cap, u_side)
        v = np.where(on_cap, v_cap, v_side)
        pid = np.where(on_cap, self.top_patch, self.side_patch).astype(np.int64)
        return n, pid, u, v

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        a_side = 2 * np.pi * self.radius * self.height
        a_top = np.pi * self.radius ** 2
        top = rng.uniform(size=n) < a_top / (a_side + a_top)
        phi = rng.uniform(0, 2 * np.pi, n)
        r = np.where(top, self.radius * np.sqrt(rng.uniform(size=n)), self.radius)
        z = np.where(top, self.base_z + self.height, rng.uniform(self.base_z, self.base_z + self.height, n))
        cx, cy = self.centre_xy.astype(np.float64)
        return np.stack([cx + r * np.cos(phi), cy + r * np.sin(phi), z], 1)


@dataclass
class Ground:
    """Plane z = 0 (normal +z) tiled with square tiles of ``tile`` units; tile
    (i, j) of a grid of ``n`` x ``n`` tiles starting at (-n*tile/2, -n*tile/2)
    uses patch ``patch_grid[i, j]`` (i along y, j along x)."""

    tile: float
    patch_grid: np.ndarray  # (n, n) int64
    radius: float           # sampling radius (the wall radius)
    lit: bool = True

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / d[2]
        return np.where((d[2] < 0) & (t > EPS_T), t, INF)

    def surface(self, p: np.ndarray):
        n = self.patch_grid.shape[0]
        gx = p[0] / F32(self.tile) + F32(n / 2)
        gy = p[1] / F32(self.tile) + F32(n / 2)
        ix = np.clip(np.floor(gx).astype(np.int64), 0, n - 1)
        iy = np.clip(np.floor(gy).astype(np.int64), 0, n - 1)
        normal = np.zeros((3, p.shape[1]), F32)
        normal[2] = 1
        return normal, self.patch_grid[iy, ix], np.clip(gx - ix, 0, 1), np.clip(1 - (gy - iy), 0, 1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        r = self.radius * np.sqrt(rng.uniform(size=n))
        phi = rng.uniform(0, 2 * np.pi, n)
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)], 1)


@dataclass
class Wall:
    """Inside of an upright cylinder of ``radius`` and ``height`` around the z axis:
    ``patch_grid[row, sector]`` covers one of n_rows x n_sectors panels
    (row 0 at the top, sectors counter-clockwise from azimuth -pi)."""

    radius: float
    height: float
    patch_grid: np.ndarray  # (n_rows, n_sectors) int64
    lit: bool = False

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        a = d[0] * d[0] + d[1] * d[1]
        b = o[0] * d[0] + o[1] * d[1]
        c = o[0] * o[0] + o[1] * o[1] - F32(self.radius ** 2)
        disc = b * b - a * c
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (-b + np.sqrt(np.maximum(disc, 0))) / a
            z = o[2] + t * d[2]
            ok = (a > 1e-12) & (disc >= 0) & (t > EPS_T) & (z >= 0) & (z <= self.height)
        return np.where(ok, t, INF)

    def surface(self, p: np.ndarray):
        rows, secs = self.patch_grid.shape
        phi = np.arctan2(p[1], p[0])
        s = (phi / F32(2 * np.pi) + F32(0.5)) * secs
        r = (1 - p[2] / F32(self.height)) * rows
        si = np.clip(np.floor(s).astype(np.int64), 0, secs - 1)
        ri = np.clip(np.floor(r).astype(np.int64), 0, rows - 1)
        rad = np.hypot(p[0], p[1])
        n = np.stack([-p[0] / rad, -p[1] / rad, np.zeros_like(rad)]).astype(F32)
        # seen from inside, azimuth grows to the viewer's left: flip u so photos are not mirrored
        return n, self.patch_grid[ri, si], np.clip(1 - (s - si), 0, 1), np.clip(r - ri, 0, 1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        phi = rng.uniform(-np.pi, np.pi, n)
        z = rng.uniform(0, self.height, n)
        return np.stack([self.radius * np.cos(phi), self.radius * np.sin(phi), z], 1)


@dataclass
class Ceiling:
    """Disk z = height (normal -z) closing the wall; one patch stretched over it."""

    radius: float
    height: float
    patch: int
    lit: bool = False

    def intersect(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (F32(self.height) - o[2]) / d[2]
        return np.where((d[2] > 0) & (t > EPS_T), t, INF)

    def surface(self, p: np.ndarray):
        n = np.zeros((3, p.shape[1]), F32)
        n[2] = -1
        u = (p[0] / F32(self.radius) + 1) / 2
        v = (p[1] / F32(self.radius) + 1) / 2
        return n, np.full(p.shape[1], self.patch, np.int64), u, v

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        r = self.radius * np.sqrt(rng.uniform(size=n))
        phi = rng.uniform(0, 2 * np.pi, n)
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.full(n, self.height)], 1)
