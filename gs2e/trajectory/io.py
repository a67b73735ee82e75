"""Trajectory files: one ``<name>.npz`` per trajectory, ``trajectories.json``
(the index) and ``trajectories.png`` (the plot), written as one atomic folder.

``<name>.npz`` arrays (load with :func:`load_trajectory`)::

    c2w (M,4,4) float64   camera-to-world poses, OpenCV axes (+x right, +y down, +z forward)
    K (3,3) float64       pinhole intrinsics in pixels; width, height: int64 pixels
    t_us (M,) int64       timestamps, microseconds from the trajectory start
    s, ds_dt (M,)         arc length at t_us and its time derivative (per us)
    curve_breaks, curve_coeffs, arc_L, arc_u, arc_du
                          the continuous representation (see gs2e.trajectory.trajectory)
    meta_json ()          JSON string: kind, method, preset, speeds, provenance
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from gs2e.codeversion import code_version
from gs2e.common.atomic import atomic_dir, write_json_atomic
from gs2e.common.errors import InputError
from gs2e.trajectory.settings import TrajectorySettings
from gs2e.trajectory.trajectory import Trajectory

INDEX_JSON = "trajectories.json"
PLOT_PNG = "trajectories.png"


def save_trajectory(path: str | os.PathLike, traj: Trajectory) -> None:
    """Write one trajectory as an uncompressed .npz (deterministic bytes)."""
    with open(path, "wb") as fh:
        np.savez(fh, **traj.to_arrays())


def load_trajectory(path: str | os.PathLike) -> Trajectory:
    """Read a trajectory file back into an evaluable :class:`Trajectory`."""
    import zipfile

    try:
        with np.load(path, allow_pickle=False) as z:
            return Trajectory.from_arrays({k: z[k] for k in z.files})
    except FileNotFoundError as exc:
        raise InputError(f"trajectory file {path} does not exist") from exc
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        # truncated or foreign files raise any of these
        raise InputError(f"cannot read trajectory file {path} (truncated or not a gs2e "
                         f"trajectory: {' '.join(str(exc).split())})") from exc


def read_index(folder: str | os.PathLike) -> dict:
    """The parsed trajectories.json of an output folder."""
    p = Path(folder) / INDEX_JSON
    try:
        return json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"cannot read {p}: {exc}") from exc


def write_outputs(out_dir: str | os.PathLike, result, cfg: TrajectorySettings, scene_dir: str,
                  plot: bool = True) -> Path:
    """Write every trajectory, the index and the plot into ``out_dir`` atomically.

    Same inputs, config and seed give the same bytes (no timings or dates inside).
    """
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        entries = []
        for name, tr in result.trajectories.items():
            save_trajectory(tmp / f"{name}.npz", tr)
            m = tr.meta
            entries.append({
                "name": name, "file": f"{name}.npz", "kind": m["kind"],
                "method": m["method"], "preset": m["preset"], "n_poses": int(len(tr.t_us)),
                "duration_us": tr.duration_us, "length": tr.length,
                "max_rel_step_error": m.get("max_rel_step_error"),
                "max_rel_step_error_chord": m.get("max_rel_step_error_chord"),
                "width": tr.width, "height": tr.height, "legs": m.get("legs", 1.0),
            })
        if plot:
            from gs2e.trajectory.plot import plot_scene
            plot_scene(result, tmp / PLOT_PNG)
        write_json_atomic(tmp / INDEX_JSON, {
            "format": "gs2e-trajectories", "version": 1, "scene": str(scene_dir),
            "code_version": code_version("trajectory"), "config": cfg.as_dict(),
            "trajectories": entries,
        })
    return out_dir
