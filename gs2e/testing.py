"""Synthetic inputs and runners shared by the tests and the benchmarks.

Not used by the pipeline. Like ``numpy.testing``, this is public so that
``tests/`` and ``benchmarks/`` use the same scenes and runners without
importing each other. The Slurm and Snakemake runners need a source
checkout: they use its ``Snakefile`` and ``workflow/scripts``.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np

from gs2e.io.scene import Camera, Frame, Scene

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
# ../shared/data beside the repo; one level further up for git worktrees (wt/<branch>)
SHARED_DATA = next((p for p in (REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data")
                    if p.is_dir()), REPO.parent / "shared" / "data")
TEMPLE = SHARED_DATA / "temple_ring" / "templeR_par.txt"

# The plane scene: :func:`plane_model` seen by the pinhole camera of :func:`straight_trajectory`.
PLANE_W, PLANE_H, PLANE_F = 64, 48, 60.0  # px, px, focal length in px
PLANE_DEPTH = 2.0  # scene units in front of the camera


def plane_model(tmp: Path) -> Path:
    """A textured plane z = DEPTH of small opaque Gaussians, as a gs2e model folder
    (``tmp``/model), seen by :func:`straight_trajectory`'s camera."""
    from skimage import data

    from gs2e.common.atomic import write_json_atomic
    from gs2e.splat.init import rgb_to_sh_dc
    from gs2e.splat.ply import write_ply

    tex = data.astronaut()[::4, ::4] / 255.0  # 128 x 128
    n = 128
    xs = (np.arange(n) - n / 2 + 0.5) * 0.03
    X, Y = np.meshgrid(xs, xs)
    means = np.stack([X.ravel(), Y.ravel(), np.full(X.size, PLANE_DEPTH)], 1)
    quats = np.tile([1.0, 0, 0, 0], (len(means), 1))
    log_scales = np.full((len(means), 3), np.log(0.02))
    opac = np.full(len(means), 6.0)
    sh = rgb_to_sh_dc(tex.reshape(-1, 3))[:, None, :]
    model = tmp / "model"
    write_ply(model / "pc.ply", means, quats, log_scales, opac, sh)
    write_json_atomic(model / "model.json", {"format": "gs2e-splat", "version": 1, "ply": "pc.ply",
                                             "iterations": 0, "sh_degree": 0})
    return model


def straight_trajectory(tmp: Path, dx: float, n_in: int = 5) -> Path:
    """Constant-velocity translation along +x over the plane, identity rotation."""
    from gs2e.io.scene import Camera, Frame, Scene
    from gs2e.trajectory.io import save_trajectory
    from gs2e.trajectory.settings import TrajectorySettings
    from gs2e.trajectory.stage import generate

    frames = []
    for i in range(n_in):
        T = np.eye(4)
        T[0, 3] = -dx / 2 + dx * i / (n_in - 1)
        frames.append(Frame(f"{i}.png", Camera(PLANE_F, PLANE_F, PLANE_W / 2, PLANE_H / 2), T))
    cfg = TrajectorySettings.defaults(velocity="1", smooth_half_width=0, view_order="sequence",
                                      interpolation="linear", speed_presets=["medium"], mini_groups=0,
                                      plot=False)
    tr = generate(Scene(PLANE_W, PLANE_H, frames, "test"), cfg, seed=0).trajectories["base_medium"]
    path = tmp / "straight.npz"
    save_trajectory(path, tr)
    return path


# ------------------------------------------------------------------ synthetic poses


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


# ----------------------------------------------------------------- the workflow
def run_group(cmd: list[str], cwd: Path, env: dict, timeout: float) -> subprocess.CompletedProcess:
    """``subprocess.run`` with captured text output, in a process group of its own
    that is killed whole on timeout or interrupt: Snakemake's job processes would
    otherwise outlive a timed-out test and slow every later one."""
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except BaseException:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        proc.communicate()
        raise
    return subprocess.CompletedProcess(cmd, proc.returncode, out, err)


def run_snakemake(*args: str, cwd: Path | None = None, timeout: float = 1500) -> subprocess.CompletedProcess:
    """Run the venv's snakemake with the repo's Snakefile."""
    e = {**os.environ, "GS2E_PROGRESS": "0",
         "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), *args]
    return run_group(cmd, cwd=cwd or REPO, env=e, timeout=timeout)


SLURM_SCRIPT = REPO / "workflow" / "scripts" / "slurm_local.sh"


def slurm_local(action: str, env: dict, timeout_s: int = 300) -> subprocess.CompletedProcess:
    """workflow/scripts/slurm_local.sh start|stop|status (the one-node test cluster)."""
    return subprocess.run(["bash", str(SLURM_SCRIPT), action], capture_output=True, text=True,
                          env=env, timeout=timeout_s)


def why_no_slurm_cluster() -> str | None:
    """Why a local Slurm cluster cannot be started here, or None if it can."""
    if shutil.which("slurmctld") and shutil.which("munged"):
        return None if os.geteuid() == 0 else "starting slurmctld/slurmd needs root"
    if os.geteuid() != 0:
        return "slurm-wlm/munge are not installed and installing them needs root"
    if shutil.which("apt-get") is None:
        return "slurm-wlm/munge are not installed and apt-get is unavailable"
    return None


# The whole workflow on a tiny demo scene (16 views at 128x96, 120 training
# steps, one 30-frame trajectory, 30 ms of events): ~1 min on 2 cores. Run
# once per test session and shared read-only by the end-to-end, rerun-audit
# and report tests (they may dry-run in it, never change its outputs).
TINY_OVERRIDES = ";".join([
    "demo.n_views=16", "demo.width=128", "demo.height=96", "demo.supersample=1",
    "sfm.reuse_poses=true",
    "splat.max_iterations=120", "splat.min_iterations=120", "splat.eval_every=60",
    "splat.densify_from=40", "splat.densify_until=100", "splat.densify_every=20",
    "splat.resolution_schedule=[[0,2],[60,1]]", "splat.checkpoint_every=0",
    "trajectory.speed_presets=[medium]", "trajectory.mini_groups=1", "trajectory.mini_frames=30",
    # a slow mini-trajectory (~0.8 s): 9 frames at 10 fps, enough views for every export
    "trajectory.presets.medium.image_speed_width_s=0.3",
    "trajectory.plot=false",
    "render.trajectories=[mini00_medium]", "render.fps=10", "render.exposure_us=20000",
    "events.max_duration_s=0.03", "render.min_coverage=0.0",
    "events.model=ideal", "events.theta_on=0.3", "events.theta_off=0.3", "events.preview=false",
])


def tiny_pipeline_args(wd: Path) -> tuple[str, ...]:
    return ("--cores", "2", "--directory", str(wd), "--config", f"scenes={wd / 'scenes.tsv'}")


def run_tiny_pipeline(wd: Path, overrides: str = TINY_OVERRIDES) -> tuple[Path, tuple[str, ...]]:
    """Run the workflow to the summary in ``wd``; returns (wd, snakemake args)."""
    wd.mkdir(parents=True, exist_ok=True)
    (wd / "scenes.tsv").write_text(f"scene_id\tlayout\tpath\toverrides\ntiny\tdemo\t\t{overrides}\n")
    args = tiny_pipeline_args(wd)
    proc = run_snakemake(*args, timeout=3600)  # cold numba caches on a slow machine: > 25 min
    if proc.returncode != 0:
        raise RuntimeError(f"tiny pipeline in {wd} failed:\n{proc.stderr[-5000:]}")
    return wd, args
