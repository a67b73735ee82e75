"""Run a model over a frame source and write the outputs (streaming, atomic).

Output folder (written as a whole, atomically)::

    events.h5      DSEC-layout events + metadata (see gs2e.events.io)
    stats.json     event statistics (gs2e.events.stats) + timings + metadata
    stats.parquet  the same statistics as one row (for the scene's metrics table)
    preview.mp4    events over the frames (optional)
    events.txt     't x y p' text (optional)
    events.npz     arrays (optional)

Memory is bounded by one batch of frames and its events, independent of the
sequence length (the npz export, when asked for, reads the events back).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path

import numpy as np

from gs2e import __version__
from gs2e.common.atomic import atomic_dir, write_json_atomic
from gs2e.common.errors import InputError
from gs2e.common.log import timed
from gs2e.common.progress import progress
from gs2e.events.io import H5EventWriter, TextEventWriter, read_h5, write_npz
from gs2e.events.models import Events, make_model
from gs2e.events.presets import effective_threshold
from gs2e.events.represent import PreviewWriter
from gs2e.events.stats import StatsAccumulator

log = logging.getLogger("gs2e.events")


def set_threads(n: int) -> int:
    """Set numba's thread count (-1 = all it has); returns the count in use."""
    import numba
    if n is not None and n > 0:
        numba.set_num_threads(min(int(n), numba.config.NUMBA_NUM_THREADS))
    else:
        numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    return numba.get_num_threads()


def _peek(source):
    """First item and an iterator that still yields it."""
    it = iter(source)
    try:
        first = next(it)
    except StopIteration:
        raise InputError(f"{getattr(source, 'name', 'frames')}: no frames") from None

    def chain():
        yield first
        yield from it
    return first, chain()


def simulate_to_folder(source, cfg: dict, out_dir: str | Path, seed: int,
                       extra_meta: dict | None = None) -> dict:
    """Simulate events for ``source`` (frame-source protocol) with the
    validated ``events`` config ``cfg``; write the output folder. Returns the
    stats dict (also written to stats.json)."""
    timings: dict[str, float] = {}
    name = getattr(source, "name", "frames")
    (t_first, f_first), frames = _peek(source)
    shape = tuple(np.asarray(f_first).shape)
    if len(shape) != 2:
        raise InputError(f"{name}: frames must be (H, W), got {shape}")
    threads = set_threads(cfg.get("num_threads", -1))
    model_seed = int(seed) + int(cfg["seed_offset"])
    model, info = make_model(cfg, shape, model_seed, source=name)
    meta = {"gs2e_version": __version__, "config": cfg, "seed": model_seed,
            "source": name, **info, **(extra_meta or {})}
    if cfg["model"] == "voltmeter":
        p = model.preset
        meta["effective_threshold"] = {
            f"rel_dL_over_L_at_{lum:g}": effective_threshold(p, info["theta_on_nominal"], lum)
            for lum in (0.1, 0.5, 1.0)}
        meta["effective_threshold"]["bright_limit"] = info["theta_on_nominal"] / p.k[0]
    H, W = shape
    acc = StatsAccumulator(shape, name=name)
    batch = int(cfg["batch_frames"])
    t0 = time.perf_counter()
    n_frames = 0
    t_last = None
    with atomic_dir(out_dir) as tmp:
        pw = (PreviewWriter(tmp / "preview.mp4", shape, cfg["preview_fps"], cfg["preview_every"])
              if cfg["preview"] else None)
        tw = TextEventWriter(tmp / "events.txt", cfg["text_polarity"]) if cfg["write_text"] else None
        ok = False
        try:
            if tw:
                tw.__enter__()
            with H5EventWriter(tmp / "events.h5", W, H, int(t_first), cfg["compression"]) as hw:
                buf_t, buf_f = [], []

                def flush():
                    nonlocal n_frames
                    ev = model.process_batch(buf_t, np.stack(buf_f))
                    hw.append(ev)
                    acc.update(ev)
                    if tw:
                        tw.append(ev)
                    if pw:
                        m = len(buf_t)
                        for i in range(m):
                            lo = buf_t[i - 1] if i > 0 else prev_t[0]
                            if lo is None:
                                continue  # the first frame closes no interval
                            a = int(np.searchsorted(ev.t, lo, side="left")) if i > 0 else 0
                            b = (int(np.searchsorted(ev.t, buf_t[i], side="left"))
                                 if i < m - 1 else len(ev))
                            pw.add(buf_f[i], Events(ev.t[a:b], ev.x[a:b], ev.y[a:b], ev.p[a:b]))
                    prev_t[0] = buf_t[-1]
                    n_frames += len(buf_t)
                    buf_t.clear()
                    buf_f.clear()

                prev_t = [None]
                for t, f in progress(frames, desc="events", total=getattr(source, "n_frames", None)):
                    if np.shape(f) != shape:
                        raise InputError(f"{name}: frame at t={t} us has shape {np.shape(f)}, "
                                         f"expected {shape} (H, W) like the first frame")
                    buf_t.append(t)
                    buf_f.append(f)
                    t_last = t
                    if len(buf_t) == batch:
                        flush()
                if buf_t:
                    flush()
                timings["simulate_s"] = time.perf_counter() - t0
                md = model.metadata()
                meta["model_metadata"] = md
                hw.attrs.update({"model": cfg["model"], "seed": model_seed,
                                 "metadata": meta, "theta/on": model.th_on.astype(np.float32),
                                 "theta/off": model.th_off.astype(np.float32)})
                hw.attrs["theta_on_summary"] = md["theta_on_map"]
                hw.attrs["theta_off_summary"] = md["theta_off_map"]
                if cfg["model"] == "voltmeter":
                    hw.attrs["preset"] = model.preset.to_dict()
            ok = True
        finally:
            if tw:
                tw.__exit__(None, None, None) if ok else tw.__exit__(RuntimeError, None, None)
            if pw:
                pw.close(ok=ok)
        if n_frames < 2:
            raise InputError(f"{name}: need at least 2 frames, got {n_frames}")
        if cfg["write_npz"]:
            ev_all, _ = read_h5(tmp / "events.h5")
            write_npz(tmp / "events.npz", ev_all, W, H)
        dur_us = float(t_last - t_first)
        stats = acc.result(duration_us=dur_us)
        stats.update(n_frames=n_frames, threads=threads, model=cfg["model"],
                     preset=cfg["preset"] if cfg["model"] == "voltmeter" else None,
                     theta_on=info["theta_on_nominal"], theta_off=info["theta_off_nominal"],
                     pixel_frames_per_s=(n_frames - 1) * H * W / max(timings["simulate_s"], 1e-9),
                     **timings)
        import pandas as pd
        row = {k: v for k, v in stats.items() if not isinstance(v, (dict, list))}
        pd.DataFrame([row]).to_parquet(tmp / "stats.parquet", index=False)
        write_json_atomic(tmp / "stats.json", {"stats": stats, "metadata": json.loads(
            json.dumps(meta, default=lambda o: o.item() if isinstance(o, np.generic) else str(o)))})
    log.info("events: %d frames (%dx%d) -> %d events (%.3f Mev/s, ON %.2f) in %.2f s",
             n_frames, W, H, stats["n_events"], stats["rate_meps"],
             stats["on_fraction"] if stats["n_events"] else float("nan"), timings["simulate_s"])
    return stats
