"""The video task on real recordings with APS frames (``bench.real_video``,
``gs2e bench-real``): the same methods as on gs2e's trajectories, scored
against the sensor's own frames, so the report can set real beside synthetic.

Every APS frame after the first is reconstructed from the events since the
first: direct integration and the complementary filter
(:func:`gs2e.bench.video.reconstruct`, crossover ``bench.video_cf_alpha_rad_s``)
from the first APS frame, with the nominal contrast ``bench.real_video_theta``
for ON and OFF (a real sensor's thresholds are not known here) and the APS
value taken as linear intensity in [0, 1]; the learned networks of
``bench.video_learned`` from a reset state, never seeing a frame, scored after
EVREAL's robust normalisation (as in the video task); and ``keyframe_held``,
the first frame itself, the reference the events have to improve on. PSNR and
SSIM against the APS frame / full scale (EVREAL's protocol on real data).

Columns of the table: recording, method, frame (the APS frame's index),
t_rel_s (since the first frame), n_events (since the previous frame), psnr,
ssim, mse, time_s (the method's wall time on that frame).
"""

from __future__ import annotations

import itertools
import time

import numpy as np

from gs2e.events.recordings import Recording
from gs2e.bench.video import KEYFRAME_HELD


def run_recording(rec: Recording, theta: float, cf_alpha_rad_s: float, learned: tuple[str, ...],
                  log_eps: float = 1e-3) -> list[dict]:
    """Per-frame rows of every method on one recording (frames 1.. after frame 0)."""
    from gs2e.bench.dataset import score
    from gs2e.bench.deblur import log_steps
    from gs2e.bench.learned import reconstruct_learned, robust_normalize
    from gs2e.bench.video import reconstruct

    ev, t_us, frames = rec.events, rec.t_us, rec.frames
    steps = log_steps(ev.p, ev.x, ev.y, theta, theta)
    q, t0 = t_us[1:], int(t_us[0])
    gens = {"integrate": reconstruct(frames[0], log_eps, ev.t, ev.x, ev.y, steps, t0, q, 0.0),
            "complementary": reconstruct(frames[0], log_eps, ev.t, ev.x, ev.y, steps, t0, q, cf_alpha_rad_s)}
    for name in learned:
        gens[name] = reconstruct_learned(name, ev, rec.shape, t_us)
    gens[KEYFRAME_HELD] = itertools.repeat(frames[0])
    edges = np.searchsorted(ev.t, t_us, side="right")
    rows = []
    for i in range(1, len(t_us)):
        for m, g in gens.items():
            t_start = time.perf_counter()
            img = next(g)
            dt = time.perf_counter() - t_start
            img = robust_normalize(img) if m in learned else img
            rows.append({"recording": rec.name, "method": m, "frame": i, "t_rel_s": (t_us[i] - t0) * 1e-6,
                         "n_events": int(edges[i] - edges[i - 1]),
                         **score(np.asarray(img, np.float64)[..., None], frames[i][..., None]), "time_s": dt})
    return rows


def run_recordings(paths, theta: float, cf_alpha_rad_s: float, learned: tuple[str, ...], out) -> None:
    """``gs2e bench-real``: read every recording first (a bad one fails before
    any work), run :func:`run_recording` on each, write ``out`` atomically."""
    import pandas as pd

    from gs2e.events.recordings import read_recording
    from gs2e.common.atomic import atomic_path, check_writable
    from gs2e.common.log import get_logger

    log = get_logger("gs2e.bench")
    check_writable(out)
    recs = [read_recording(p) for p in paths]
    rows = []
    for rec in recs:
        t0 = time.perf_counter()
        got = run_recording(rec, theta, cf_alpha_rad_s, learned)
        d = pd.DataFrame(got).groupby("method", sort=False)["psnr"].mean()
        log.info("%s: %d APS frames, %d events, %.1f s; mean PSNR %s", rec.name, len(rec.t_us),
                 len(rec.events), time.perf_counter() - t0, ", ".join(f"{m} {v:.2f}" for m, v in d.items()))
        rows += got
    cols = ["recording", "method", "frame", "t_rel_s", "n_events", "psnr", "ssim", "mse", "time_s"]
    with atomic_path(out) as tmp:
        pd.DataFrame(rows, columns=cols).to_parquet(tmp, index=False)
