"""I/O of Gaussian models in the official 3DGS layout (REFERENCE.md section 5).

``point_cloud.ply``: binary little-endian, one ``vertex`` element of float32
properties ``x y z nx ny nz f_dc_0..2 f_rest_0..M-1 opacity scale_0..2
rot_0..3`` where f_rest is channel-major (all R coefficients of degrees >= 1,
then G, then B), opacity is a logit, scales are natural logs and rot is a
(w, x, y, z) quaternion normalised at use. Stored at
``<model>/point_cloud/iteration_<N>/point_cloud.ply``.

``cameras.json``: a list of ``{id, img_name, width, height, position,
rotation, fx, fy}`` with position the camera centre and rotation the 3x3
camera-to-world rotation (OpenCV/COLMAP axes); the principal point is the
image centre.

Readers accept files from the official code, gsplat exports and viewers
(extra properties ignored, normals optional, any numeric property type) and
raise :class:`~gs2e.common.errors.InputError` naming the file on missing
attributes, NaN/inf, a wrong SH count or corruption. Writers are atomic.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gs2e.common.atomic import atomic_file
from gs2e.common.errors import InputError

SH_BASES = (1, 4, 9, 16)  # K for degrees 0..3


@dataclass
class Gaussians:
    """A Gaussian model as numpy arrays (float32 or float64).

    means (N,3) world positions; quats (N,4) (w,x,y,z), any non-zero norm;
    log_scales (N,3) natural-log std devs; opacity_logits (N,); sh (N,K,3)
    SH coefficients with K in {1,4,9,16} (colour = SH + 0.5).
    """

    means: np.ndarray
    quats: np.ndarray
    log_scales: np.ndarray
    opacity_logits: np.ndarray
    sh: np.ndarray

    def __post_init__(self) -> None:
        n = self.means.shape[0] if self.means.ndim == 2 else -1
        want = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
        for name, shp in want.items():
            if getattr(self, name).shape != shp:
                raise InputError(f"Gaussians.{name} must have shape {shp}, "
                                 f"got {getattr(self, name).shape}")
        if self.sh.ndim != 3 or self.sh.shape[0] != n or self.sh.shape[2] != 3 \
                or self.sh.shape[1] not in SH_BASES:
            raise InputError(f"Gaussians.sh must have shape (N,K,3) with K in {SH_BASES}, "
                             f"got {self.sh.shape}")

    @property
    def n(self) -> int:
        return int(self.means.shape[0])

    @property
    def sh_degree(self) -> int:
        return SH_BASES.index(self.sh.shape[1])

    def to_torch(self, dtype=None, requires_grad: bool = False) -> dict:
        """Tensors keyed like the arguments of :func:`gs2e.splat.rasterize.rasterize`."""
        import torch
        dtype = dtype or torch.float32
        return {k: torch.tensor(np.ascontiguousarray(getattr(self, k)), dtype=dtype,
                                requires_grad=requires_grad)
                for k in ("means", "quats", "log_scales", "opacity_logits", "sh")}

    @classmethod
    def from_torch(cls, params: dict) -> "Gaussians":
        return cls(**{k: params[k].detach().cpu().numpy() for k in
                      ("means", "quats", "log_scales", "opacity_logits", "sh")})


def ply_property_names(sh_degree: int) -> list[str]:
    """Vertex properties of the official layout, in order."""
    K = SH_BASES[sh_degree]
    return (["x", "y", "z", "nx", "ny", "nz"] + [f"f_dc_{i}" for i in range(3)]
            + [f"f_rest_{i}" for i in range(3 * (K - 1))] + ["opacity"]
            + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])


def write_ply(path: str | Path, g: Gaussians) -> None:
    """Write ``g`` as an official-layout ``point_cloud.ply`` (float32), atomically.

    Raises InputError (naming the file) if the model holds NaN/inf.
    """
    from plyfile import PlyData, PlyElement

    path = Path(path)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh"):
        if not np.isfinite(getattr(g, name)).all():
            raise InputError(f"{path}: refusing to write a model whose {name} holds NaN/inf")
    names = ply_property_names(g.sh_degree)
    K = g.sh.shape[1]
    cols = [g.means, np.zeros((g.n, 3)), g.sh[:, 0, :],
            # channel-major: (N, K-1, 3) -> (N, 3, K-1) -> flat
            np.transpose(g.sh[:, 1:, :], (0, 2, 1)).reshape(g.n, 3 * (K - 1)),
            g.opacity_logits[:, None], g.log_scales, g.quats]
    data = np.concatenate([np.asarray(c, dtype=np.float64).reshape(g.n, -1) for c in cols], axis=1)
    arr = np.empty(g.n, dtype=[(nm, "<f4") for nm in names])
    for i, nm in enumerate(names):
        arr[nm] = data[:, i]
    ply = PlyData([PlyElement.describe(arr, "vertex")], text=False, byte_order="<")
    with atomic_file(path, "wb") as fh:
        ply.write(fh)


def read_ply(path: str | Path, dtype=np.float32) -> Gaussians:
    """Read an official-layout ``point_cloud.ply`` (3DGS, gsplat, viewers).

    Raises InputError naming the file on a missing file or attribute, a
    corrupt file, an SH count that is not 3*(K-1) for K in 1,4,9,16, NaN/inf
    values or zero-norm quaternions.
    """
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: Gaussian model file not found")
    try:
        ply = PlyData.read(str(path))
        vert = ply["vertex"]
        props = [p.name for p in vert.properties]
        data = vert.data
    except KeyError:
        raise InputError(f"{path}: no 'vertex' element (not a Gaussian point_cloud.ply)") from None
    except Exception as e:  # plyfile raises several types on corrupt input
        raise InputError(f"{path}: unreadable PLY ({type(e).__name__}: {e})") from None
    required = (["x", "y", "z", "opacity"] + [f"f_dc_{i}" for i in range(3)]
                + [f"scale_{i}" for i in range(3)] + [f"rot_{i}" for i in range(4)])
    missing = [p for p in required if p not in props]
    if missing:
        raise InputError(f"{path}: missing vertex attribute(s) {missing}")
    rest = sorted((int(m.group(1)) for p in props if (m := re.fullmatch(r"f_rest_(\d+)", p))))
    if rest != list(range(len(rest))):
        raise InputError(f"{path}: f_rest_* attributes are not numbered 0..{len(rest) - 1}")
    if len(rest) % 3 or (len(rest) // 3 + 1) not in SH_BASES:
        raise InputError(f"{path}: {len(rest)} f_rest attributes; expected 0, 9, 24 or 45 "
                         "(SH degree 0-3)")
    K = len(rest) // 3 + 1
    n = len(data)
    if n == 0:
        raise InputError(f"{path}: the model has no Gaussians")

    def col(names):
        try:
            out = np.stack([np.asarray(data[nm], dtype=np.float64) for nm in names], axis=1)
        except (ValueError, TypeError) as e:
            raise InputError(f"{path}: attribute(s) {names} are not numeric ({e})") from None
        bad = ~np.isfinite(out)
        if bad.any():
            which = [names[j] for j in np.flatnonzero(bad.any(axis=0))]
            raise InputError(f"{path}: {int(bad.sum())} NaN/inf value(s) in attribute(s) {which}")
        return out

    means = col(["x", "y", "z"])
    dc = col([f"f_dc_{i}" for i in range(3)])
    fr = col([f"f_rest_{i}" for i in range(3 * (K - 1))]) if K > 1 else np.zeros((n, 0))
    sh = np.empty((n, K, 3))
    sh[:, 0, :] = dc
    sh[:, 1:, :] = np.transpose(fr.reshape(n, 3, K - 1), (0, 2, 1))
    quats = col([f"rot_{i}" for i in range(4)])
    if (np.linalg.norm(quats, axis=1) == 0).any():
        raise InputError(f"{path}: {int((np.linalg.norm(quats, axis=1) == 0).sum())} "
                         "zero-norm rotation quaternion(s)")
    return Gaussians(means.astype(dtype), quats.astype(dtype),
                     col([f"scale_{i}" for i in range(3)]).astype(dtype),
                     col(["opacity"])[:, 0].astype(dtype), sh.astype(dtype))


def point_cloud_path(model_dir: str | Path, iteration: int) -> Path:
    """``<model_dir>/point_cloud/iteration_<N>/point_cloud.ply``."""
    return Path(model_dir) / "point_cloud" / f"iteration_{int(iteration)}" / "point_cloud.ply"


def latest_point_cloud(model_dir: str | Path) -> tuple[Path, int]:
    """The PLY of the highest saved iteration in an official model folder."""
    root = Path(model_dir) / "point_cloud"
    its = []
    if root.is_dir():
        for d in root.iterdir():
            m = re.fullmatch(r"iteration_(\d+)", d.name)
            if m and (d / "point_cloud.ply").is_file():
                its.append(int(m.group(1)))
    if not its:
        raise InputError(f"{root}: no iteration_*/point_cloud.ply found")
    return point_cloud_path(model_dir, max(its)), max(its)


@dataclass
class CameraEntry:
    """One record of the official ``cameras.json`` (OpenCV axes, c2w)."""

    id: int
    img_name: str
    width: int
    height: int
    c2w: np.ndarray  # (4,4) camera-to-world
    fx: float
    fy: float

    def to_json(self) -> dict:
        return {"id": int(self.id), "img_name": self.img_name, "width": int(self.width),
                "height": int(self.height), "position": self.c2w[:3, 3].tolist(),
                "rotation": self.c2w[:3, :3].tolist(), "fx": float(self.fx), "fy": float(self.fy)}

    def splat_camera(self, near: float = 0.01, far: float = 1.0e10):
        """A :class:`~gs2e.splat.rasterize.SplatCamera` (principal point at the centre)."""
        from gs2e.splat.rasterize import SplatCamera
        return SplatCamera.from_c2w(self.c2w, self.fx, self.fy, self.width / 2.0,
                                    self.height / 2.0, self.width, self.height, near, far)


def write_cameras_json(path: str | Path, cams: list[CameraEntry]) -> None:
    """Write the official ``cameras.json`` atomically."""
    with atomic_file(path, "w") as fh:
        json.dump([c.to_json() for c in cams], fh, indent=1)


def read_cameras_json(path: str | Path) -> list[CameraEntry]:
    """Read an official ``cameras.json``; InputError naming the file and entry."""
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"{path}: cameras file not found") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(raw, list) or not raw:
        raise InputError(f"{path}: expected a non-empty list of cameras")
    out = []
    for i, d in enumerate(raw):
        where = f"{path}: camera {i}"
        if not isinstance(d, dict):
            raise InputError(f"{where} is not an object")
        missing = [k for k in ("id", "img_name", "width", "height", "position", "rotation",
                               "fx", "fy") if k not in d]
        if missing:
            raise InputError(f"{where} lacks key(s) {missing}")
        try:
            pos = np.asarray(d["position"], dtype=np.float64).reshape(3)
            rot = np.asarray(d["rotation"], dtype=np.float64).reshape(3, 3)
            w, h, fx, fy = int(d["width"]), int(d["height"]), float(d["fx"]), float(d["fy"])
        except (ValueError, TypeError) as e:
            raise InputError(f"{where}: malformed values ({e})") from None
        if not (np.isfinite(pos).all() and np.isfinite(rot).all() and np.isfinite([fx, fy]).all()):
            raise InputError(f"{where}: NaN/inf in position, rotation or focal length")
        if w <= 0 or h <= 0 or fx <= 0 or fy <= 0:
            raise InputError(f"{where}: width, height, fx, fy must be > 0")
        if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-4 or np.linalg.det(rot) <= 0:
            raise InputError(f"{where}: rotation is not a proper rotation matrix")
        c2w = np.eye(4)
        c2w[:3, :3] = rot
        c2w[:3, 3] = pos
        out.append(CameraEntry(int(d["id"]), str(d["img_name"]), w, h, c2w, fx, fy))
    return out


def cameras_from_scene(scene) -> list[CameraEntry]:
    """cameras.json records for the posed frames of a :class:`gs2e.io.scene.Scene`."""
    out = []
    for i, f in enumerate(scene.frames):
        if f.c2w is None:
            continue
        out.append(CameraEntry(i, Path(f.name).stem, scene.width, scene.height,
                               np.asarray(f.c2w, dtype=np.float64), f.camera.fx, f.camera.fy))
    return out
