"""Simulated against real events on the same scene under the same motion.

A real recording of a static scene with its camera's ground-truth path (an
ECD sequence such as ``../shared/data/slider_depth``) is rebuilt by gs2e from
its own APS frames and poses (``gs2e ingest --layout ecd``, structure from
motion with the given poses, training). Along the recorded path, sampled
densely, the trained model is rendered once; each event-model variant
simulates events from those frames, and the events are compared with the
real ones over the time both cover:

* ``count_ratio``: simulated / real events (distance: ``|log ratio|``);
* ``on_fraction``: ON events / all (distance: absolute difference);
* ``count_corr`` / ``count_l1``: per-pixel event counts over windows of
  ``window_us``: Pearson correlation (distance 1 - r) and the L1 distance
  after matching the total rate (sum |c_sim N_real / N_sim - c_real| / N_real,
  0 = same maps, 2 = disjoint); ``count_corr_pooled``: the correlation of the
  counts pooled over 4 x 4 pixel blocks (what survives sub-pixel pose and
  calibration errors);
* ``rate_l1``: the rate over time in 1 ms bins, each normalised to its total,
  L1 distance (0 = same shape, 2 = disjoint);
* ``iei_w1``: per-pixel inter-event intervals, the 1-Wasserstein distance of
  their log10 (decades);
* ``edge_fraction``: events on the strongest image edges (the 20 % of pixels
  with the largest APS gradient) / all; distance: absolute difference from
  the real events'.

Each distance comes with its ``floor``: the distance between the variant and
itself at another seed (another threshold-mismatch map, other noise). A real
sensor's own mismatch map is unknown, so no simulation with mismatch gets
closer to it, pixel by pixel, than about its floor.

Geometry: the real events are undistorted into the trained scene's pinhole
camera (their pixel centres moved with the calibration, rounded to the
nearest pixel); the APS frames too, for the edge maps. The APS is linear in
intensity: a grey value the model reproduces is taken as linear luminance,
not sRGB (``aps_linear``).

The pure functions (:func:`compare_events`, :func:`fit_model`,
:func:`simulate_frames`) work on arrays; :func:`run_sim2real` is the I/O edge
(``gs2e bench-sim2real``).
"""

from __future__ import annotations

import copy
import logging
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events, make_model
from gs2e.events.represent import window_events

log = logging.getLogger("gs2e.bench")

METRICS = ("count_ratio", "on_fraction", "count_corr", "count_corr_pooled", "count_l1", "rate_l1",
           "iei_w1", "edge_fraction")
POOL_PX = 4
EDGE_QUANTILE = 0.8
RATE_BIN_US = 1000


@dataclass(frozen=True)
class Sim2RealSettings:
    """``bench.sim2real_*``: what is compared and how densely it is rendered.

    ``fps``: renders per second along the recorded path; ``window_us``: the
    count maps' window; ``warmup_us``: simulated but not compared (a
    simulation starts with every pixel at its reference level, a running
    sensor does not); ``variants``: event-model settings compared (see
    :func:`variant_settings`); ``fit``: the event models (``ideal``,
    ``voltmeter``) whose thresholds, mismatch and refractory period are also
    fitted to the recording (:func:`fit_model`; variant ``fitted_<model>``);
    ``seed``: the models' seed.
    """

    fps: float
    window_us: int
    warmup_us: int
    variants: tuple[str, ...]
    fit: tuple[str, ...]
    aps_linear: bool
    seed: int = 0


# ---------------------------------------------------------------- geometry
def _cv_cameras(calib, K: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's (K_src, dist, K_dst): gs2e puts the centre of pixel 0 at 0.5,
    OpenCV at 0; gs2e's OPENCV / FULL_OPENCV distortion order is OpenCV's."""
    K_src, K_dst = calib.K.copy(), np.asarray(K, np.float64).copy()
    K_src[:2, 2] -= 0.5
    K_dst[:2, 2] -= 0.5
    if calib.model not in ("PINHOLE", "SIMPLE_PINHOLE", "OPENCV", "FULL_OPENCV"):
        raise InputError(f"sim-to-real reads pinhole or OpenCV calibrations, not {calib.model}")
    dist = np.zeros(4) if not calib.dist else np.asarray(calib.dist, np.float64)
    return K_src, dist, K_dst


def events_in_camera(ev: Events, calib, K: np.ndarray, width: int, height: int) -> Events:
    """Real events (pixel indices of the distorted sensor, ``calib`` a
    :class:`gs2e.io.scene.Camera` in gs2e's pixel-centre convention) moved
    into the pinhole camera ``K`` (gs2e convention) of ``width`` x ``height``:
    undistorted, rounded to the nearest pixel; events landing outside are
    dropped. Time order is kept."""
    import cv2

    if len(ev) == 0:
        return ev
    K_src, dist, K_dst = _cv_cameras(calib, K)
    pts = np.stack([ev.x, ev.y], axis=1).astype(np.float64)[:, None, :]
    und = cv2.undistortPoints(pts, K_src, dist, R=None, P=K_dst,
                              criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-9))[:, 0]
    x, y = np.rint(und[:, 0]), np.rint(und[:, 1])
    ok = (x >= 0) & (x < width) & (y >= 0) & (y < height)
    return Events(ev.t[ok], x[ok].astype(np.uint16), y[ok].astype(np.uint16), ev.p[ok])


def frame_in_camera(img: np.ndarray, calib, K: np.ndarray, width: int, height: int) -> np.ndarray:
    """An APS frame of the distorted sensor resampled into the pinhole camera ``K``."""
    import cv2

    K_src, dist, K_dst = _cv_cameras(calib, K)
    m1, m2 = cv2.initUndistortRectifyMap(K_src, dist, None, K_dst, (width, height), cv2.CV_32FC1)
    return cv2.remap(np.asarray(img, np.float32), m1, m2, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def edge_mask(img: np.ndarray, quantile: float = EDGE_QUANTILE) -> np.ndarray:
    """(H, W) bool: the pixels whose gradient magnitude (Sobel, 3x3) is in the
    top ``1 - quantile`` of the image."""
    import cv2

    f = np.asarray(img, np.float32)
    g = np.hypot(cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3))
    return g >= np.quantile(g, quantile)


# ---------------------------------------------------------------- comparison
def rate_bins(ev: Events, t0_us: int, t1_us: int) -> np.ndarray:
    """Events per :data:`RATE_BIN_US` bin over [t0_us, t1_us) (the last bin may
    be shorter; ``ev`` already within the span)."""
    nb = max(1, -(-(t1_us - t0_us) // RATE_BIN_US))
    return np.bincount(np.minimum((ev.t - t0_us) // RATE_BIN_US, nb - 1), minlength=nb)


def count_maps(ev: Events, shape: tuple[int, int], t0_us: int, t1_us: int, window_us: int) -> np.ndarray:
    """(n_windows, H, W) int64 event counts per window of ``window_us`` over
    [t0_us, t1_us) (the last window may be shorter)."""
    H, W = shape
    n = max(1, -(-(t1_us - t0_us) // window_us))
    w = np.clip((ev.t - t0_us) // window_us, 0, n - 1)
    idx = (w * H + ev.y.astype(np.int64)) * W + ev.x.astype(np.int64)
    return np.bincount(idx, minlength=n * H * W).reshape(n, H, W)


def _pool(maps: np.ndarray, k: int) -> np.ndarray:
    """(n, H, W) -> (n, ceil(H/k), ceil(W/k)) sums over k x k blocks."""
    n, H, W = maps.shape
    Hp, Wp = -(-H // k) * k, -(-W // k) * k
    pad = np.zeros((n, Hp, Wp), maps.dtype)
    pad[:, :H, :W] = maps
    return pad.reshape(n, Hp // k, k, Wp // k, k).sum(axis=(2, 4))


def _iei_log10(ev: Events, W: int) -> np.ndarray:
    from gs2e.events.stats import per_pixel_intervals

    _, iei = per_pixel_intervals(ev, W)
    return np.log10(np.maximum(iei, 1).astype(np.float64))


def compare_events(sim: Events, real: Events, shape: tuple[int, int], t0_us: int, t1_us: int,
                   window_us: int, edges: np.ndarray | None = None) -> dict:
    """Distances between simulated and real events over [t0_us, t1_us)
    (both time-sorted, in the same camera; see the module docstring).

    Returns ``{metric: {"sim", "real", "distance"}}`` for :data:`METRICS`;
    a value that cannot be computed (no events, no intervals) is NaN.
    """
    from scipy.stats import wasserstein_distance

    sim, real = window_events(sim, t0_us, t1_us), window_events(real, t0_us, t1_us)
    ns, nr = len(sim), len(real)
    nan = float("nan")
    out = {}
    out["count_ratio"] = {"sim": float(ns), "real": float(nr),
                          "distance": abs(math.log(ns / nr)) if ns and nr else nan}
    on_s = float(sim.p.mean()) if ns else nan
    on_r = float(real.p.mean()) if nr else nan
    out["on_fraction"] = {"sim": on_s, "real": on_r, "distance": abs(on_s - on_r)}
    cs = count_maps(sim, shape, t0_us, t1_us, window_us).ravel().astype(np.float64)
    cr = count_maps(real, shape, t0_us, t1_us, window_us).ravel().astype(np.float64)
    r = (float(np.corrcoef(cs, cr)[0, 1]) if ns and nr and cs.std() > 0 and cr.std() > 0 else nan)
    out["count_corr"] = {"sim": r, "real": 1.0, "distance": 1.0 - r}
    ps, pr = (_pool(c.reshape(-1, *shape), POOL_PX).ravel() for c in (cs, cr))
    rp = (float(np.corrcoef(ps, pr)[0, 1]) if ns and nr and ps.std() > 0 and pr.std() > 0 else nan)
    out["count_corr_pooled"] = {"sim": rp, "real": 1.0, "distance": 1.0 - rp}
    l1 = float(np.abs(cs * (nr / ns) - cr).sum() / nr) if ns and nr else nan
    out["count_l1"] = {"sim": l1, "real": 0.0, "distance": l1}
    rs, rr = rate_bins(sim, t0_us, t1_us), rate_bins(real, t0_us, t1_us)
    rl1 = float(np.abs(rs / ns - rr / nr).sum()) if ns and nr else nan
    out["rate_l1"] = {"sim": rl1, "real": 0.0, "distance": rl1}
    ls, lr = _iei_log10(sim, shape[1]), _iei_log10(real, shape[1])
    w1 = float(wasserstein_distance(ls, lr)) if len(ls) and len(lr) else nan
    out["iei_w1"] = {"sim": float(np.median(ls)) if len(ls) else nan,
                     "real": float(np.median(lr)) if len(lr) else nan, "distance": w1}
    if edges is not None:
        es = float(edges[sim.y, sim.x].mean()) if ns else nan
        er = float(edges[real.y, real.x].mean()) if nr else nan
        out["edge_fraction"] = {"sim": es, "real": er, "distance": abs(es - er)}
    else:
        out["edge_fraction"] = {"sim": nan, "real": nan, "distance": nan}
    return out


# ---------------------------------------------------------------- simulation
def simulate_frames(settings: dict, ts_us: np.ndarray, frames: np.ndarray, seed: int) -> Events:
    """All events of an in-memory frame sequence ((N,) int us, (N, H, W)
    linear luminance) under an ``events`` section (a dict)."""
    from gs2e.events.readout import SensorChain, resolve_readout
    from gs2e.events.settings import event_settings

    cfg = event_settings(settings)
    model, _ = make_model(cfg, frames.shape[1:], int(seed), source="sim2real")
    return SensorChain(model, resolve_readout(cfg)[0], int(seed)).simulate(ts_us, frames)


# what every variant other than the scene's own sets: one threshold each, as given
FIXED_THETA = {"theta_sampling": "fixed", "theta_on_off_independent": False}
_VOLTMETER_K = {f"k{i}": None for i in range(1, 7)}


def variant_settings(name: str, scene_events: dict) -> dict:
    """The ``events`` section of a named variant.

    ``scene``: the scene's own section (its sensor's noise and readout
    included); ``ideal``: the ideal model at threshold 0.2 (log units), no
    noise; ``voltmeter``: DVS-Voltmeter with its DAVIS346 preset (``dvs346``,
    its own k1..k6) at 1.0, no noise; a sensor name
    (:data:`gs2e.events.sensors.SENSORS`): that sensor's pixel
    non-idealities and readout parts and, where it has them, its fitted
    model, preset and thresholds. Frames are already rendered, so a sensor's
    pixel array changes nothing here: the comparison is pixel by pixel in
    the recording's camera.
    """
    from gs2e.events.sensors import NOISE_KEYS, READOUT_KEYS, SENSORS

    base = {k: v for k, v in copy.deepcopy(scene_events).items() if k != "max_duration_s"}
    if name == "scene":
        return base
    quiet = {**{k: None for k in (*NOISE_KEYS, *READOUT_KEYS, "theta_mismatch_rel")},
             "sensor": None, "sensor_file": None, **FIXED_THETA}
    if name == "ideal":
        return {**base, **quiet, "model": "ideal", "theta_on": 0.2, "theta_off": 0.2}
    if name == "voltmeter":
        return {**base, **quiet, **_VOLTMETER_K, "model": "voltmeter", "preset": "dvs346",
                "theta_on": 1.0, "theta_off": 1.0}
    if name not in SENSORS:
        raise ConfigError(f"bench.sim2real_variants: unknown variant '{name}' (choose from scene, "
                          f"ideal, voltmeter, {', '.join(SENSORS)})")
    # the sensor's own values: config keys that would win over them are cleared
    out = {**base, **quiet, "sensor": name}
    model = SENSORS[name].extra.get("model")
    if model:
        out.update(model=model["value"], theta_on=model["theta_on"], theta_off=model["theta_off"])
        if model["value"] == "voltmeter":
            out.update(preset=model.get("preset", "dvs346"), **_VOLTMETER_K)
    return out


def total_distance(d: dict) -> float:
    """The sum of a comparison's finite distances: what the joint fit
    minimises (a metric that cannot be computed, e.g. edges without an APS
    frame, adds nothing)."""
    v = [d[m]["distance"] for m in METRICS]
    return float(sum(x for x in v if np.isfinite(x)))


# ---------------------------------------------------------------- calibration
@dataclass
class FitResult:
    """An event model fitted to a recording: thresholds (the model's units),
    the threshold mismatch relative to each polarity's threshold, the
    refractory period (us) and the distances at the fit; ``history`` lists
    every trial."""

    model: str
    theta_on: float
    theta_off: float
    mismatch_rel: float
    refractory_us: float
    distances: dict
    history: list = field(default_factory=list)

    def settings(self, base: dict) -> dict:
        return fit_settings(base, self.model, self.theta_on, self.theta_off, self.mismatch_rel,
                            self.refractory_us)


def fit_settings(base: dict, model: str, theta_on: float, theta_off: float, mismatch_rel: float,
                 refractory_us: float) -> dict:
    """The ``events`` section of one trial of a fit: ``base`` with the model,
    fixed thresholds, relative mismatch and refractory period; no noise, no
    sensor, no readout parts (a still-free recording pins none of them)."""
    from gs2e.events.sensors import NOISE_KEYS, READOUT_KEYS

    out = {**base, **{k: None for k in READOUT_KEYS}, **{k: 0.0 for k in NOISE_KEYS},
           "shot_noise_on_fraction": 0.5, "sensor": None, "sensor_file": None, **FIXED_THETA,
           "model": model, "theta_on": float(theta_on), "theta_off": float(theta_off),
           "theta_mismatch_sigma": None, "theta_mismatch_rel": float(mismatch_rel),
           "refractory_us": float(refractory_us)}
    if model == "voltmeter":  # the DAVIS346 calibration of the public code, whatever the scene's
        out.update(preset="dvs346", **_VOLTMETER_K)
    return out


NOMINAL_THETA = {"ideal": 0.2, "voltmeter": 1.0}  # where the threshold search is centred


def fit_model(model: str, ts_us: np.ndarray, frames: np.ndarray, real: Events, t0_us: int, t1_us: int,
              window_us: int, base: dict, seed: int = 0, edges=None,
              theta_grid=None, ratio_grid=None, mismatch_grid=(0.0, 0.05, 0.1, 0.15, 0.2, 0.3),
              refractory_grid=(0.0, 100.0, 300.0, 1000.0, 3000.0, 10000.0)) -> FitResult:
    """Fit ``model`` (``ideal``, or ``voltmeter`` with its ``dvs346`` preset)
    to real events of the same frames by coordinate search, one
    parameter per distance it governs:

    1. the threshold scale (ON = OFF) to the event count (``count_ratio``);
    2. the ON/OFF ratio at the same geometric mean to the ON fraction;
    3. the relative mismatch to the count maps (``count_l1``);
    4. the refractory period to the intervals (``iei_w1``);
    5. the scale again, to the count;
    6. jointly, scale x refractory period x mismatch on a small grid around
       the values found, to the sum of all distances (:func:`total_distance`).

    ``base``: the other ``events`` keys (a dict). Deterministic for a seed.
    """
    if model not in NOMINAL_THETA:
        raise ConfigError(f"bench.sim2real_fit: cannot fit model '{model}' (one of {', '.join(NOMINAL_THETA)})")
    nominal = NOMINAL_THETA[model]
    theta_grid = nominal * np.geomspace(0.25, 5.0, 25) if theta_grid is None else np.asarray(theta_grid)
    ratio_grid = np.geomspace(0.5, 2.0, 13) if ratio_grid is None else np.asarray(ratio_grid)
    shape = frames.shape[1:]
    history = []

    def trial(scale, ratio, mis, refr):
        on, off = scale * math.sqrt(ratio), scale / math.sqrt(ratio)
        s = fit_settings(base, model, on, off, mis, refr)
        d = compare_events(simulate_frames(s, ts_us, frames, seed), real, shape, t0_us, t1_us,
                           window_us, edges)
        history.append({"theta_scale": float(scale), "on_off_ratio": float(ratio),
                        "mismatch_rel": float(mis), "refractory_us": float(refr),
                        **{m: d[m]["distance"] for m in METRICS}})
        return d

    def best(values, make, metric):
        scores = []
        for v in values:
            d = make(v)
            scores.append(d[metric]["distance"] if np.isfinite(d[metric]["distance"]) else np.inf)
        return values[int(np.argmin(scores))]

    scale, ratio, mis, refr = nominal, 1.0, 0.0, 0.0
    scale = best(theta_grid, lambda v: trial(v, ratio, mis, refr), "count_ratio")
    ratio = best(ratio_grid, lambda v: trial(scale, v, mis, refr), "on_fraction")
    mis = best(list(mismatch_grid), lambda v: trial(scale, ratio, v, refr), "count_l1")
    refr = best(list(refractory_grid), lambda v: trial(scale, ratio, mis, v), "iei_w1")
    fine = scale * np.geomspace(0.85, 1.15, 7)
    scale = best(fine, lambda v: trial(v, ratio, mis, refr), "count_ratio")
    joint = [(sc, rf, mi) for sc in scale * np.geomspace(0.85, 1 / 0.85, 5)  # 1 at the centre
             for rf in sorted({0.0, refr / 3, refr, refr * 3} if refr else {0.0, 30.0, 100.0})
             for mi in sorted({max(0.0, mis - 0.05), mis, mis + 0.05})]
    totals = [total_distance(trial(sc, ratio, mi, rf)) for sc, rf, mi in joint]
    scale, refr, mis = joint[int(np.argmin(totals))]
    d = trial(scale, ratio, mis, refr)
    return FitResult(model, float(scale * math.sqrt(ratio)), float(scale / math.sqrt(ratio)), float(mis),
                     float(refr), d, history)


# ---------------------------------------------------------------- the I/O edge
def recorded_path(ecd_folder: str | Path, scene_dir: str | Path):
    """The recording's ground-truth path as a gs2e trajectory in the scene's
    (undistorted) camera; times from the first ground-truth pose. Returns
    (trajectory, t_offset_us: the recording time of trajectory time 0)."""
    from gs2e.io.ecd import read_groundtruth
    from gs2e.io.scene import read_scene
    from gs2e.trajectory.trajectory import recorded_trajectory

    scene = read_scene(scene_dir)
    cam = scene.frames[0].camera
    if cam.model not in ("PINHOLE", "SIMPLE_PINHOLE"):
        raise InputError(f"{scene_dir}: the trained scene's camera is {cam.model}; sim-to-real renders "
                         "a pinhole camera (run structure from motion, which undistorts)")
    t_s, c2w = read_groundtruth(Path(ecd_folder) / "groundtruth.txt")
    off_us = int(round(t_s[0] * 1e6))
    t_us = np.round(t_s * 1e6).astype(np.int64) - off_us
    traj = recorded_trajectory(t_us, c2w, cam.K, scene.width, scene.height,
                               {"source": str(Path(ecd_folder) / "groundtruth.txt"),
                                "t_offset_us": off_us})
    return traj, off_us


def render_path(model_dir, traj_path, t0_us: int, t1_us: int, fps: float, aps_linear: bool,
                background=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """(ts_us (N,), frames (N, H, W) float32) linear luminance rendered by the
    event stage's renderer at ``fps`` over [t0_us, t1_us] (trajectory time).
    ``aps_linear``: the model's grey values are linear (an APS), not sRGB."""
    from gs2e.common.color import linear_to_srgb
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.settings import event_settings

    cfg = event_settings({"sampling": {"mode": "fixed", "fixed_fps": float(fps)}})
    src = RenderedSource(model_dir, traj_path, cfg,
                         background=background, span_us=(int(t0_us), int(t1_us)))
    t_first, f_first = src.start()
    ts, fr = [int(t_first)], [np.array(f_first)]
    for t_b, f_b in src.batches():
        ts.extend(int(t) for t in t_b)
        fr.extend(np.array(f) for f in f_b)
    frames = np.stack(fr)
    if aps_linear:  # the renderer decoded sRGB; the APS value itself is the luminance
        frames = np.clip(linear_to_srgb(frames), 0.0, 1.0).astype(np.float32)
    return np.asarray(ts, np.int64), frames


def run_sim2real(model_dir, scene_dir, ecd_folder, out_dir, scene_events: dict,
                 settings: Sim2RealSettings) -> dict:
    """Render the recorded path, simulate every variant (and the fit), compare
    with the real events; write ``distances.parquet`` (one row per variant x
    metric, with its floor), ``fit.json``, ``trajectory.npz`` and ``sim2real.png`` into
    ``out_dir`` atomically. Returns the run summary."""
    from gs2e.events.recordings import read_ecd
    from gs2e.common.atomic import atomic_dir, json_safe, write_json_atomic
    from gs2e.io.ecd import read_calib
    from gs2e.metrics.table import write_metrics
    from gs2e.trajectory.io import save_trajectory

    ecd_folder = Path(ecd_folder)
    calib = read_calib(ecd_folder / "calib.txt")
    rec = read_ecd(ecd_folder)
    for v in settings.variants:
        variant_settings(v, scene_events)  # unknown names fail before any work
    traj, off_us = recorded_path(ecd_folder, scene_dir)
    W, H = traj.width, traj.height
    real = events_in_camera(rec.events, calib, traj.K, W, H)
    real = Events(real.t - off_us, real.x, real.y, real.p)
    t0 = max(0, int(real.t[0]) if len(real) else 0)
    t1 = min(int(traj.t_us[-1]), int(real.t[-1]) + 1 if len(real) else 0)
    tc = t0 + settings.warmup_us  # compared from here on
    if t1 - tc < 2 * settings.window_us:
        raise InputError(f"{ecd_folder}: the events and the ground truth overlap for "
                         f"{max(0, t1 - t0)} us, less than the warm-up and two windows")
    timings = {}
    with atomic_dir(out_dir) as tmp:
        save_trajectory(tmp / "trajectory.npz", traj)
        a = time.perf_counter()
        ts, frames = render_path(model_dir, tmp / "trajectory.npz", t0, t1, settings.fps,
                                 settings.aps_linear)
        timings["render_s"] = time.perf_counter() - a
        aps_t = rec.t_us - off_us
        mid = (t0 + t1) // 2
        k = int(np.argmin(np.abs(aps_t - mid)))
        aps = frame_in_camera(rec.frames[k], calib, traj.K, W, H)
        edges = edge_mask(aps)
        rows, sims = [], {}

        def add(name: str, ev_settings: dict) -> None:
            a = time.perf_counter()
            ev = simulate_frames(ev_settings, ts, frames, settings.seed)
            timings[f"simulate_{name}_s"] = time.perf_counter() - a
            sims[name] = ev
            d = compare_events(ev, real, (H, W), tc, t1, settings.window_us, edges)
            # the same settings at another seed: how far the variant is from itself
            other = simulate_frames(ev_settings, ts, frames, settings.seed + 1)
            f = compare_events(other, ev, (H, W), tc, t1, settings.window_us, edges)
            rows.extend({"variant": name, "metric": m, **d[m], "floor": f[m]["distance"]}
                        for m in METRICS)

        for name in settings.variants:
            add(name, variant_settings(name, scene_events))
        fits = {}
        for model in settings.fit:
            a = time.perf_counter()
            fit = fit_model(model, ts, frames, real, tc, t1, settings.window_us, scene_events,
                            settings.seed, edges)
            timings[f"fit_{model}_s"] = time.perf_counter() - a
            fits[model] = fit
            add(f"fitted_{model}", fit.settings(scene_events))
        write_metrics(tmp / "distances.parquet", rows)
        summary = {"recording": str(ecd_folder), "t0_us": t0, "compared_from_us": tc, "t1_us": t1,
                   "t_offset_us": off_us, "n_real": len(window_events(real, tc, t1)), "n_frames": int(len(ts)),
                   "shape": [H, W], "aps_frame_us": int(rec.t_us[k]), "settings": asdict(settings),
                   "timings": timings,
                   "fits": {m: {k2: v for k2, v in asdict(f).items() if k2 != "history"}
                            for m, f in fits.items()}}
        write_json_atomic(tmp / "fit.json", json_safe(
            {**summary, "fit_history": {m: f.history for m, f in fits.items()}}))
        plot_sim2real(tmp / "sim2real.png", real, sims, (H, W), t0, t1, settings.window_us, aps, tc)
    log.info("sim2real: %d real events over %.3f s, %d frames; %s", summary["n_real"],
             (t1 - t0) * 1e-6, len(ts), ", ".join(f"{k} {v:.1f} s" for k, v in timings.items()))
    return summary


def plot_sim2real(path, real: Events, sims: dict, shape, t0_us: int, t1_us: int, window_us: int,
                  aps: np.ndarray, compared_from_us: int | None = None) -> None:
    """Side by side: the APS frame, then one window's events (ON red, OFF blue)
    of the real recording and each variant; below, the rates over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gs2e.common.atomic import atomic_file

    mid = (t0_us + t1_us) // 2
    a, b = mid - window_us // 2, mid + window_us // 2
    panels = [("real", real), *sims.items()]
    fig, ax = plt.subplots(2, len(panels) + 1, figsize=(2.6 * (len(panels) + 1), 5.2),
                           gridspec_kw={"height_ratios": [1, 0.8]})
    ax[0, 0].imshow(aps, cmap="gray", vmin=0, vmax=1)
    ax[0, 0].set_title("APS (undistorted)", fontsize=8)
    for i, (name, ev) in enumerate(panels, start=1):
        e = window_events(ev, a, b)
        img = np.ones((*shape, 3))
        on, off = e.p == 1, e.p == 0
        img[e.y[on], e.x[on]] = (0.85, 0.1, 0.1)
        img[e.y[off], e.x[off]] = (0.1, 0.2, 0.85)
        ax[0, i].imshow(img)
        ax[0, i].set_title(f"{name}: {len(e)} ev / {window_us / 1000:g} ms", fontsize=8)
    for a_ in ax[0]:
        a_.axis("off")
    gs = ax[1, 0].get_gridspec()
    for a_ in ax[1]:
        a_.remove()
    axr = fig.add_subplot(gs[1, :])
    for name, ev in panels:
        r = rate_bins(window_events(ev, t0_us, t1_us), t0_us, t1_us)
        tt = (t0_us + (np.arange(len(r)) + 0.5) * RATE_BIN_US) * 1e-3
        axr.plot(tt, r / (RATE_BIN_US * 1e-6) / 1e6, lw=2.0 if name == "real" else 1.0,
                 color="k" if name == "real" else None, label=name)
    if compared_from_us is not None:
        axr.axvspan(t0_us * 1e-3, compared_from_us * 1e-3, color="0.9", zorder=0, label="warm-up")
    axr.set_xlabel("time on the recorded path (ms)")
    axr.set_ylabel("event rate (Mev/s)")
    axr.legend(fontsize=7, ncol=len(panels))
    fig.tight_layout()
    with atomic_file(path, "wb") as fh:
        fig.savefig(fh, format="png", dpi=90)
    plt.close(fig)


def settings_from_config(bench: dict, seed: int = 0) -> Sim2RealSettings:
    """The typed settings of a validated ``bench`` section."""
    return Sim2RealSettings(fps=float(bench["sim2real_fps"]),
                            window_us=int(round(float(bench["sim2real_window_ms"]) * 1000)),
                            warmup_us=int(round(float(bench["sim2real_warmup_ms"]) * 1000)),
                            variants=tuple(bench["sim2real_variants"]),
                            fit=tuple(bench["sim2real_fit"]), aps_linear=bool(bench["sim2real_aps_linear"]),
                            seed=int(seed))
