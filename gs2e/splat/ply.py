"""Official 3D Gaussian Splatting file formats.

``point_cloud.ply``: binary little-endian, one ``vertex`` element of float32
properties ``x y z nx ny nz f_dc_0..2 f_rest_0..M-1 opacity scale_0..2
rot_0..3`` where M = 3*((d+1)^2 - 1) for SH degree d (45 for d=3). ``f_rest``
is channel-major: all R coefficients, then G, then B. ``opacity`` is a logit,
``scale_*`` are natural logs, ``rot`` is (w, x, y, z) and normalised at use.
The colour of SH degree 0 is ``SH_C0 * f_dc + 0.5``.

``cameras.json``: a list of ``{id, img_name, width, height, position,
rotation, fx, fy}`` with ``position`` the camera centre and ``rotation`` the
camera-to-world rotation (rows), OpenCV axes.

Arrays here: means (N,3), quats (N,4) wxyz, log_scales (N,3), opacity_logits
(N,), sh (N,K,3) with K = (d+1)^2 coefficients per colour channel.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from gs2e.common.atomic import atomic_path, write_json_atomic
from gs2e.common.errors import InputError

_BASE = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
_TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
REST_COUNT_TO_DEGREE = {0: 0, 9: 1, 24: 2, 45: 3}


def sh_degree_of(n_coeffs: int) -> int:
    d = int(round(math.sqrt(n_coeffs))) - 1
    if (d + 1) ** 2 != n_coeffs or not 0 <= d <= 3:
        raise ValueError(f"{n_coeffs} SH coefficients per channel is not (d+1)^2 for d in 0..3")
    return d


def write_ply(path: str | Path, means: np.ndarray, quats: np.ndarray, log_scales: np.ndarray,
              opacity_logits: np.ndarray, sh: np.ndarray) -> None:
    """Write Gaussians in the official layout (atomically). Rejects NaN/inf."""
    from plyfile import PlyData, PlyElement

    means = np.asarray(means, np.float32)
    n = means.shape[0]
    sh = np.asarray(sh, np.float32)
    arrays = {"means": means, "quats": np.asarray(quats, np.float32),
              "log_scales": np.asarray(log_scales, np.float32),
              "opacity_logits": np.asarray(opacity_logits, np.float32).reshape(n), "sh": sh}
    shapes = {"means": (n, 3), "quats": (n, 4), "log_scales": (n, 3), "opacity_logits": (n,)}
    for k, shp in shapes.items():
        if arrays[k].shape != shp:
            raise ValueError(f"{k} has shape {arrays[k].shape}, expected {shp}")
    if sh.ndim != 3 or sh.shape[0] != n or sh.shape[2] != 3:
        raise ValueError(f"sh has shape {sh.shape}, expected (N, K, 3)")
    sh_degree_of(sh.shape[1])
    for k, a in arrays.items():
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{k} contains NaN or inf; refusing to write {path}")
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # channel-major
    names = _BASE + [f"f_rest_{i}" for i in range(rest.shape[1])] + _TAIL
    cols = [means, np.zeros((n, 3), np.float32), sh[:, 0, :], rest,
            arrays["opacity_logits"][:, None], arrays["log_scales"], arrays["quats"]]
    data = np.concatenate(cols, axis=1)
    vertex = np.empty(n, dtype=[(nm, "<f4") for nm in names])
    for i, nm in enumerate(names):
        vertex[nm] = data[:, i]
    with atomic_path(path) as tmp:
        PlyData([PlyElement.describe(vertex, "vertex")], byte_order="<").write(str(tmp))


def read_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read an official-layout ``point_cloud.ply``; returns float32 arrays
    ``means, quats, log_scales, opacity_logits, sh`` (see module docstring).

    Raises InputError naming the file for unreadable files, missing attributes,
    an SH count that is not 0/9/24/45 rest coefficients, or NaN/inf values.
    """
    from plyfile import PlyData

    path = Path(path)
    try:
        # memory-mapped: plyfile's unmapped path parses row by row (1.9 s for 24k Gaussians,
        # minutes for millions); it checks the file holds every row first, so a truncated
        # file still raises here, and the arrays below are copies (files are replaced by
        # rename, never truncated in place)
        ply = PlyData.read(str(path), mmap="c")
        v = ply["vertex"].data
    except Exception as exc:  # plyfile raises several types for corrupt input
        raise InputError(f"cannot read Gaussian model {path}: {exc}") from exc
    if len(v) == 0:
        raise InputError(f"{path}: the model has no Gaussians (0 vertices)")
    names = set(v.dtype.names or ())
    missing = [nm for nm in ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", *_TAIL] if nm not in names]
    if missing:
        raise InputError(f"{path}: missing vertex attributes {', '.join(missing)}")
    n_rest = len([nm for nm in names if nm.startswith("f_rest_")])
    if n_rest not in REST_COUNT_TO_DEGREE or any(f"f_rest_{i}" not in names for i in range(n_rest)):
        raise InputError(f"{path}: {n_rest} f_rest_* attributes; expected 0, 9, 24 or 45 (SH degree 0-3)")

    def cols(keys):
        return np.stack([np.asarray(v[k], np.float32) for k in keys], axis=1)

    n = len(v)
    k = n_rest // 3 + 1
    sh = np.empty((n, k, 3), np.float32)
    sh[:, 0, :] = cols(["f_dc_0", "f_dc_1", "f_dc_2"])
    if n_rest:
        sh[:, 1:, :] = cols([f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k - 1).transpose(0, 2, 1)
    out = {
        "means": cols(["x", "y", "z"]),
        "quats": cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        "log_scales": cols(["scale_0", "scale_1", "scale_2"]),
        "opacity_logits": np.array(v["opacity"], np.float32),  # a copy, not a view of the map
        "sh": sh,
    }
    for key, a in out.items():
        bad = ~np.isfinite(a.reshape(n, -1)).all(axis=1) if n else np.zeros(0, bool)
        if bad.any():
            raise InputError(f"{path}: {int(bad.sum())} Gaussians have NaN/inf in {key} "
                             f"(first at vertex {int(np.argmax(bad))})")
    if n and np.any(np.linalg.norm(out["quats"], axis=1) == 0):
        raise InputError(f"{path}: zero-length rotation quaternion")
    return out


def cameras_json_entries(scene) -> list[dict]:
    """cameras.json entries for the frames of a gs2e Scene (OpenCV c2w poses)."""
    entries = []
    for i, f in enumerate(scene.frames):
        if f.c2w is None:
            raise InputError(f"frame {f.name} has no pose")
        w, h = scene.frame_size(i)
        entries.append({
            "id": i, "img_name": Path(f.name).stem, "width": w, "height": h, "position": f.c2w[:3, 3].tolist(),
            "rotation": f.c2w[:3, :3].tolist(), "fx": float(f.camera.fx), "fy": float(f.camera.fy),
        })
    return entries


def write_cameras_json(path: str | Path, scene) -> None:
    write_json_atomic(path, cameras_json_entries(scene))


def read_cameras_json(path: str | Path) -> list[dict]:
    """Entries with ``c2w`` (4,4) added; validates shapes and finiteness."""
    from gs2e.io.scene import check_pose

    path = Path(path)
    try:
        entries = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read {path}: {exc}") from exc
    for e in entries:
        try:
            T = np.eye(4)
            T[:3, :3] = np.asarray(e["rotation"], float)
            T[:3, 3] = np.asarray(e["position"], float)
            e["c2w"] = check_pose(T, f"{path} camera {e.get('img_name', e.get('id'))}")
        except KeyError as exc:
            raise InputError(f"{path}: camera entry lacks {exc}") from exc
    return entries
