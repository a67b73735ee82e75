"""Event-stage runs that several benchmarks share, so that no script imports
another: the trained scenes that bench_event_sampling.py builds and caches,
the tests' textured plane panning fast, one in-process sampling run feeding
the event models, ``gs2e events`` on the cost model's trained models
(bench_cost_model.py ``--run``), and per-pixel event counts and their
distances.

gs2e is imported inside the functions, so that a script's ``--help`` does not
load the kernels.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from harness import REPO, RESULTS, SHARED_SCENES, clock, gs2e_env, report, run_child

CACHE = RESULTS / "bench_event_sampling_cache"
THETA_IDEAL = 0.2
PAPER_FPS = 2400.0
REF_MOTION_PX = 0.05  # image motion between the dense reference's renders
# name -> (scenes-table layout, input path, overrides): 2000 training steps each
SCENES = {
    "demo": ("demo", "", "splat.max_iterations=2000"),
    **{n: (SHARED_SCENES[n][0], str(SHARED_SCENES[n][1]), "ingest.max_side=320;splat.max_iterations=2000")
       for n in ("temple_ring", "llff_fern")},
    # its own COLMAP cameras: SfM at 320 px registers too few of its views
    "mouse_colmap": (SHARED_SCENES["mouse_colmap"][0], str(SHARED_SCENES["mouse_colmap"][1]),
                     "sfm.reuse_poses=true;ingest.max_side=320;splat.max_iterations=2000"),
}


# ------------------------------------------------------------------ scenes
def build_scenes(names: list[str]) -> dict[str, Path]:
    """Trained models and trajectories of :data:`SCENES` ``names`` through the
    workflow, cached in :data:`CACHE` (about 15-30 min on 2 cores when absent);
    name -> results folder of the scene (``splat/``, ``trajectories/``)."""
    CACHE.mkdir(parents=True, exist_ok=True)
    rows = ["scene_id\tlayout\tpath\toverrides"]
    for n in names:
        layout, path, over = SCENES[n]
        built = all((CACHE / "results" / n / d).exists() for d in ("splat", "trajectories"))
        if layout != "demo" and not built and not Path(path).exists():
            raise SystemExit(f"{path} is missing (../shared/data): cannot benchmark {n}")
        rows.append(f"{n}\t{layout}\t{path}\t{over}")
    (CACHE / "scenes.tsv").write_text("\n".join(rows) + "\n")
    targets = [f"results/{n}/{d}" for n in names for d in ("splat", "trajectories")]
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
               GS2E_PROGRESS="0")
    todo = [t for t in targets if not (CACHE / t).exists()]
    if todo:
        print(f"building {', '.join(todo)} (cached in {CACHE}) ...", flush=True)
        subprocess.run([str(Path(sys.executable).parent / "snakemake"), "--snakefile",
                        str(REPO / "Snakefile"), "--cores", "2", "--directory", str(CACHE),
                        "--config", f"scenes={CACHE / 'scenes.tsv'}", "results_dir=results",
                        "--", *todo], check=True, env=env)
    return {n: CACHE / "results" / n for n in names}


def plane_scene(tmp: Path) -> tuple[Path, Path]:
    """The tests' textured plane (64 x 48 px, :func:`gs2e.testing.plane_model`)
    and a pan 10x faster than 'strong'; (model folder, trajectory file) under ``tmp``."""
    from gs2e.io.scene import Camera, Frame, Scene
    from gs2e.testing import PLANE_F as F, PLANE_H as H, PLANE_W as W, plane_model
    from gs2e.trajectory.io import save_trajectory
    from gs2e.trajectory.settings import TrajectorySettings
    from gs2e.trajectory.stage import generate
    from gs2e.trajectory.trajectory import Trajectory

    model = plane_model(tmp)
    frames = []
    for i in range(7):
        a = np.deg2rad(-8 + 16 * i / 6)
        T = np.eye(4)
        T[:3, :3] = [[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]]
        T[0, 3], T[1, 3] = -0.1 + 0.2 * i / 6, 0.05 * np.sin(i)
        frames.append(Frame(f"{i}.png", Camera(F, F, W / 2, H / 2), T))
    cfg = TrajectorySettings.defaults(view_order="sequence", speed_presets=["strong"], mini_groups=0,
                                      plot=False, velocity="0.6*sin(6*t)+1.0")
    tr = generate(Scene(W, H, frames, "plane"), cfg, seed=0).trajectories["base_strong"]
    d = tr.to_arrays()
    d["t_us"] = np.round(d["t_us"] / 10.0).astype(np.int64)
    d["ds_dt"] = d["ds_dt"] * 10.0
    path = tmp / "plane_pan.npz"
    save_trajectory(path, Trajectory.from_arrays(d))
    return model, path


# ------------------------------------------------------------------ in-process runs
def events_cfg(model: str, mode: str, fps: float = 2400.0, bound: float = 1.0,
               extra: dict | None = None) -> dict:
    """The events section for ``model`` sampled by ``mode`` (``fps``: fixed
    rate in Hz; ``bound``: bound_fraction); ``extra``: more keys of the
    section (a ``sampling`` entry is merged into sampling). The ideal model
    has thresholds of :data:`THETA_IDEAL` log units."""
    from gs2e.config import load_config

    ev = {"model": model, "sampling": {"mode": mode, "fixed_fps": fps, "bound_fraction": bound}}
    if model == "ideal":
        ev.update(theta_on=THETA_IDEAL, theta_off=THETA_IDEAL)
    extra = dict(extra or {})
    ev["sampling"].update(extra.pop("sampling", {}))
    ev.update(extra)
    return load_config({"events": ev})["events"]


def run(model_dir, traj, span, mode, fps=2400.0, bound=1.0, seeds=(0,),
        sample_for=("ideal", "voltmeter"), extra: dict | None = None) -> dict:
    """One sampling run over ``span`` (us, us) feeding the ideal model and/or
    DVS-Voltmeter (one per seed); events, rendered pixel values, sample times
    and timings in seconds (wall, and process CPU of the whole run). Adaptive
    modes sample the signal of the model they feed (``sample_for`` one model);
    fixed-rate and motion-clock samples do not depend on it and feed both.
    ``extra``: see :func:`events_cfg`."""
    from gs2e.events.models import Events, TileBatch, make_model
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings

    cfg = events_cfg(sample_for[0], mode, fps, bound, extra)
    src = RenderedSource(model_dir, traj, event_settings(cfg), span_us=span, batch_frames=64)
    with clock() as whole:
        t0, f0 = src.start()
        models = {}
        if "ideal" in sample_for:
            models["ideal"] = make_model(event_settings(events_cfg("ideal", mode, fps, bound, extra)),
                                         src.shape, 0)[0]
        for s in seeds if "voltmeter" in sample_for else ():
            vm = event_settings(events_cfg("voltmeter", mode, extra=extra))
            models[f"voltmeter{s}"] = make_model(vm, src.shape, s)[0]
        for m in models.values():
            m.start(t0, f0)
        out = {k: [] for k in models}
        model_s = dict.fromkeys(models, 0.0)
        times = [np.array([t0], np.int64)]
        for item in src.batches():
            times.append(item.t1_us if isinstance(item, TileBatch) else item[0])
            for k, m in models.items():
                b = time.perf_counter()  # summed per model over the batches
                out[k].append(m.process_tiles(item) if isinstance(item, TileBatch) else m.process_batch(*item))
                model_s[k] += time.perf_counter() - b
        for k, m in models.items():
            out[k].append(m.flush())
    st = src.stats
    return {"events": {k: Events.concat(v) for k, v in out.items()}, "shape": src.shape,
            "pixel_samples": st.pixel_samples, "renders": st.renders, "rejected": st.rejected,
            "forced": st.forced, "windows": st.windows, "times_us": np.unique(np.concatenate(times)),
            "render_s": whole.wall_s - sum(model_s.values()), "model_s": model_s,
            "wall_s": whole.wall_s, "cpu_s": whole.cpu_s, "duration_us": src.duration_us}


def motion_rate_px_per_us(src, t_us: int) -> float:
    """Image motion of a ``RenderedSource`` (px per us,
    :func:`gs2e.splat.forward.image_motion_px`) at ``t_us``, over 200 us."""
    from gs2e.splat.forward import image_motion_px

    t1 = min(t_us + 200, src.t1_us)
    r = src.renderer
    return image_motion_px(r.centres(src.pose_at(t_us)), r.centres(src.pose_at(t1))) / max(1, t1 - t_us)


def reference_span(src, ref_renders: int, max_span_us: int) -> tuple[int, int]:
    """(t0, t1) us: a span from the middle of ``src``'s trajectory in full
    motion, as long as ``ref_renders`` renders :data:`REF_MOTION_PX` apart
    allow (at most ``max_span_us``, at least 100 us)."""
    t_mid = (src.t0_us + src.t1_us) // 2
    rate = motion_rate_px_per_us(src, t_mid)
    span_us = int(min(max_span_us, src.t1_us - t_mid, ref_renders * REF_MOTION_PX / max(rate, 1e-12)))
    return t_mid, t_mid + max(span_us, 100)


def reference_run(model_dir, traj, span, extra: dict | None = None, seeds=(0,),
                  sample_for=("ideal", "voltmeter")) -> dict:
    """:func:`run` of the dense reference: whole renders at most
    :data:`REF_MOTION_PX` of image motion apart (the ``motion`` clock, steps
    down to 1 us), whatever rate that takes."""
    extra = dict(extra or {})
    return run(model_dir, traj, span, "motion", seeds=seeds, sample_for=sample_for, extra={
        **extra, "sampling": {**extra.get("sampling", {}), "max_motion_px": REF_MOTION_PX,
                              "dt_min_us": 1}})


# ------------------------------------------------------------------ values between renders
SLOPE_DT_US = 2.0  # one-sided differences standing in for exact time derivatives


def hermite(g0, d0, g1, d1, s):
    """Cubic Hermite curve through g0, g1 with slopes d0, d1 (per step) at s in [0, 1]."""
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * g0 + (s3 - 2 * s2 + s) * d0 + (3 * s2 - 2 * s3) * g1
            + (s3 - s2) * d1)


def exact_slope(G, t, g, h, lo=-np.inf, hi=np.inf):
    """The time derivative of ``G`` at ``t`` per step ``h`` (``g`` = G(t)):
    of the one-sided differences over :data:`SLOPE_DT_US` (inside [lo, hi]) the
    smaller in magnitude, so that a Gaussian crossing the opacity cut-off
    within them does not count as a slope."""
    fwd = G(t + SLOPE_DT_US) - g if t + SLOPE_DT_US <= hi else None
    bwd = g - G(t - SLOPE_DT_US) if t - SLOPE_DT_US >= lo else None
    d = (bwd if fwd is None else fwd if bwd is None
         else np.where(np.abs(fwd) < np.abs(bwd), fwd, bwd))
    return d * (h / SLOPE_DT_US)


# ------------------------------------------------------------------ comparing events
def pixel_keys(ev, W: int) -> np.ndarray:
    """Pixel and polarity of each event as one index, (y * W + x) * 2 + p."""
    return (ev.y.astype(np.int64) * W + ev.x.astype(np.int64)) * 2 + ev.p.astype(np.int64)


def pixel_counts(ev, width: int, height: int) -> np.ndarray:
    """Events per pixel and polarity, (2 * height * width,) indexed by :func:`pixel_keys`."""
    return np.bincount(pixel_keys(ev, width), minlength=2 * width * height)


def count_error(ev, ref, shape) -> float:
    """sum |n - n_ref| / sum n_ref over pixels x polarities; ``shape`` (H, W)."""
    H, W = shape
    a = pixel_counts(ev, W, H)
    b = pixel_counts(ref, W, H)
    return float(np.abs(a - b).sum() / max(1, b.sum()))


def count_distance(a: np.ndarray, b: np.ndarray) -> float:
    """sum |a - b| over pixels x polarities, over the mean event count (both
    from :func:`pixel_counts`)."""
    return float(np.abs(a - b).sum() / max(1.0, 0.5 * (a.sum() + b.sum())))


def matched_dt_us(ev, ref, shape) -> np.ndarray:
    """|t - t_ref| (us) of the events matched in order per pixel and polarity
    (the k-th ON event of a pixel with the reference's k-th, ...)."""
    H, W = shape

    def ranked(e):
        k = pixel_keys(e, W)
        o = np.lexsort((e.t, k))
        ks = k[o]
        return ks * (1 << 32) + (np.arange(len(ks)) - np.searchsorted(ks, ks, side="left")), e.t[o]

    ia_id, ta = ranked(ev)
    ib_id, tb = ranked(ref)
    _, ia, ib = np.intersect1d(ia_id, ib_id, assume_unique=True, return_indices=True)
    return np.abs(ta[ia] - tb[ib])


# ------------------------------------------------------------------ the cost model's runs
def cost_run(sensor: str) -> tuple[Path, dict]:
    """The results folder of bench_cost_model.py's ``--run`` at ``sensor``
    (benchmarks/results/cost_<sensor>/results) and its resolved config."""
    import yaml

    from gs2e.config import load_config

    work = RESULTS / f"cost_{sensor}"
    if not (work / "config.yaml").exists():
        raise SystemExit(f"{work}/config.yaml is absent: run "
                         f"`python benchmarks/bench_cost_model.py --run SCENE --sensor {sensor}` first")
    return work / "results", load_config(yaml.safe_load((work / "config.yaml").read_text()))


def cost_run_scenes(sensor: str) -> list[str]:
    """The scenes bench_cost_model.py's ``--run`` at ``sensor`` has trained
    (sorted; empty when it has not run here)."""
    results = RESULTS / f"cost_{sensor}" / "results"
    return sorted(p.parent.name for p in results.glob("*/splat/model.json")) if results.is_dir() else []


def scenes_of_cost_run(ap, args, what: str) -> bool:
    """Fill ``args.scenes`` with every scene the cost run at ``args.sensor``
    trained, unless given. False when it trained none: then a usage error,
    or with ``--quick`` the headline says what was not measured."""
    args.scenes = args.scenes or ",".join(cost_run_scenes(args.sensor))
    if args.scenes:
        return True
    how = f"python benchmarks/bench_cost_model.py --run SCENE --sensor {args.sensor}"
    if not args.quick:
        ap.error(f"the cost run at {args.sensor} has trained no scene: give --scenes, or run {how} first")
    report(None, f"{what} not measured: no cost run at {args.sensor} here ({how} trains its models)")
    return False


def run_events(scene_dir: Path, traj: str, events_cfg: dict, mode: str, fps: float, bound: float,
               seed: int, span_s: float, out: Path, repo: Path = REPO, model: Path | None = None) -> dict:
    """``gs2e events`` (a fresh process, 2 threads) on the first ``span_s`` seconds
    of trajectory ``traj`` of ``scene_dir`` with the code of checkout ``repo``
    and the scene's model (or ``model``): CPU seconds of the process (all its
    threads), wall seconds, its stats and events."""
    from gs2e.events.io import read_h5

    cfg = json.loads(json.dumps(events_cfg))
    cfg.update(max_duration_s=span_s, containers=[], preview=False, write_text=False, write_npz=False)
    cfg["sampling"].update(mode=mode, fixed_fps=fps, bound_fraction=bound)
    cmd = [sys.executable, "-m", "gs2e", "events", "--model", str(model or scene_dir / "splat"),
           "--trajectory", str(scene_dir / "trajectories" / f"{traj}.npz"), "-o", str(out),
           "--seed", str(seed), "--threads", "2", "--config-json", json.dumps(cfg)]
    r = run_child(cmd, env=gs2e_env(repo), cwd=repo)
    if r.returncode != 0:
        raise SystemExit(f"gs2e events ({repo}) failed: {r.output.strip()[-500:]}")
    st = json.loads((out / "stats.json").read_text())["stats"]
    ev, _ = read_h5(out / "events.h5")
    return {"cpu_s": r.cpu_s, "wall_s": r.wall_s, "stats": st, "events": ev}
