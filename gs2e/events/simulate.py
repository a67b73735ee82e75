"""Run a model over a sample source and write the outputs (streaming, atomic).

Output folder (written as a whole, atomically)::

    events.h5      DSEC-layout events + metadata (see gs2e.events.io)
    stats.json     event statistics (gs2e.events.stats) + sampling cost + timings + metadata
    stats.parquet  the same statistics as one row (for the scene's metrics table)
    preview.mp4    events over the luminance, one video frame per
                   ``preview_window_ms`` of simulated time (optional)
    events.txt     't x y p' text (optional)
    events.npz     arrays (optional)
    events.aedat4, events.raw (EVT2), events.dat
                   the same events in the containers of ``events.containers``
                   (gs2e.events.containers; the sensor's size in each header)

Sources: a frame source (``(t_us, frame)`` pairs, :mod:`gs2e.events.frames`)
or a rendered source (:class:`gs2e.events.rendered.RenderedSource`: whole
frames or tile batches, by ``events.sampling.mode``). Memory is bounded by one
batch and the events the model holds back at its horizon, independent of the
sequence length (the npz export, when asked for, reads the events back).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Iterator

import numba
import numpy as np

from gs2e import __version__
from gs2e.common.atomic import atomic_dir, write_json_atomic
from gs2e.common.errors import ConfigError, InputError
from gs2e.common.progress import progress
from gs2e.common.settings import require
from gs2e.events.containers import CONTAINERS, ContainerWriter, container_limits
from gs2e.events.io import H5EventWriter, TextEventWriter, read_h5, write_npz
from gs2e.events.models import Events, TileBatch, make_model
from gs2e.events.readout import SensorChain, resolve_readout
from gs2e.events.represent import PreviewWriter
from gs2e.events.settings import EventSettings
from gs2e.events.stats import StatsAccumulator

log = logging.getLogger("gs2e.events")


class FrameBatches:
    """A frame source as the simulator's input: ``start()`` gives the first
    frame, ``batches()`` groups of ``batch`` frames ((B,) int64 times, (B, H, W));
    ``luminance`` is the latest frame (previews)."""

    def __init__(self, frames, batch: int = 32):
        self.src, self.batch = frames, int(batch)
        self.name = getattr(frames, "name", "frames")
        self.n_frames = getattr(frames, "n_frames", None)
        self.stats = None
        self._it = iter(frames)

    def start(self) -> tuple[int, np.ndarray]:
        try:
            t, f = next(self._it)
        except StopIteration:
            raise InputError(f"{self.name}: no frames") from None
        f = np.asarray(f)
        if f.ndim != 2:
            raise InputError(f"{self.name}: frames must be (H, W), got {f.shape}")
        self.shape = f.shape
        self.luminance = f
        return t, f

    def batches(self) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        ts, fs = [], []
        for t, f in self._it:
            if np.shape(f) != self.shape:
                raise InputError(f"{self.name}: frame at t={t} us has shape {np.shape(f)}, "
                                 f"expected {self.shape} (H, W) like the first frame")
            ts.append(t)
            fs.append(f)
            if len(ts) == self.batch:
                self.luminance = fs[-1]
                yield ts, np.stack(fs)
                ts, fs = [], []
        if ts:
            self.luminance = fs[-1]
            yield ts, np.stack(fs)


class _PreviewWindows:
    """Feeds a PreviewWriter one video frame per ``window_us`` of event time."""

    def __init__(self, pw: PreviewWriter, t0_us: int, window_us: int):
        self.pw, self.w = pw, max(1, int(window_us))
        self.end = t0_us + self.w
        self.parts: list[Events] = []

    def add(self, ev: Events, horizon: int | None, luminance) -> None:
        """``ev``: the next events (sorted, all before ``horizon``; None = the end)."""
        while True:
            cut = int(np.searchsorted(ev.t, self.end, side="left"))
            self.parts.append(Events(ev.t[:cut], ev.x[:cut], ev.y[:cut], ev.p[:cut]))
            ev = Events(ev.t[cut:], ev.x[cut:], ev.y[cut:], ev.p[cut:])
            if not (len(ev) or (horizon is not None and horizon >= self.end)):
                break
            self.pw.add(luminance, Events.concat(self.parts))
            self.parts = []
            self.end += self.w

    def finish(self, luminance) -> None:
        self.pw.add(luminance, Events.concat(self.parts))


def _check_containers(containers: tuple[str, ...], name: str, W: int, H: int, t_first_us: int) -> None:
    """Before any simulation: ConfigError for a size no chosen container
    holds, InputError for negative times (containers store unsigned ones)."""
    for kind in containers:
        why = container_limits(kind, W, H)
        if why:
            raise ConfigError(f"events.containers: {why}")
    if containers and t_first_us < 0:
        raise InputError(f"{name}: events.containers {list(containers)} cannot store negative "
                         f"times (first frame at {t_first_us} us)")


def _run_chain(source, chain, emit, bar, t_first_us: int, clock: dict) -> int:
    """Feed every batch of ``source`` through the sensor ``chain``, passing
    its events to ``emit(events, horizon_us)``; time spent goes to
    ``clock['source_s']`` / ``clock['model_s']``, progress (ms) to ``bar``.
    Returns the time (us) of the last sample."""
    t_last, done_ms = t_first_us, 0
    batches = iter(source.batches())
    while True:
        a = time.perf_counter()
        item = next(batches, None)
        b = time.perf_counter()
        clock["source_s"] += b - a
        if item is None:
            return t_last
        if isinstance(item, TileBatch):
            ev = chain.process_tiles(item)
            t_last = max(t_last, int(item.t1_us.max()))
        else:
            ev = chain.process_batch(*item)
            t_last = int(item[0][-1])
        clock["model_s"] += time.perf_counter() - b
        emit(ev, chain.horizon_us)
        now_ms = max(0, (chain.horizon_us - t_first_us) // 1000)
        bar.update(now_ms - done_ms)
        done_ms = now_ms


def _write_attrs(hw, model, chain, meta: dict, model_name: str, seed: int) -> dict:
    """events.h5's attributes: the run's metadata (``meta`` gains the model's
    and the chain's as ``model_metadata``, which is returned), the per-pixel
    thresholds and the model's own attributes."""
    md = model.metadata()
    md.update(chain.describe())
    meta["model_metadata"] = md
    hw.attrs.update({"model": model_name, "seed": seed, "metadata": meta,
                     "theta/on": model.th_on.astype(np.float32), "theta/off": model.th_off.astype(np.float32)})
    hw.attrs["theta_on_summary"] = md["theta_on_map"]
    hw.attrs["theta_off_summary"] = md["theta_off_map"]
    hw.attrs.update(model.file_attrs())
    return md


def simulate_to_folder(source, settings: EventSettings, out_dir: str | Path, seed: int,
                       extra_meta: dict | None = None) -> dict:
    """Simulate events for ``source`` (a frame source, or an object with
    ``start()``/``batches()`` like :class:`gs2e.events.rendered.RenderedSource`)
    with the ``events`` settings (:class:`EventSettings`); write the output
    folder. Returns the stats dict (also written to stats.json)."""
    settings = require(settings, EventSettings, "simulate_to_folder")
    if not hasattr(source, "batches"):
        source = FrameBatches(source, settings.batch_frames)
    timings: dict[str, float] = {}
    name = source.name
    t_start = time.perf_counter()
    t_first, f_first = source.start()
    f_first = np.asarray(f_first)
    shape = tuple(f_first.shape)
    H, W = shape
    _check_containers(settings.containers, name, W, H, int(t_first))
    threads = numba.get_num_threads()  # set by the caller (gs2e.common.threads); recorded only
    model_seed = int(seed) + int(settings.seed_offset)
    model, info = make_model(settings, shape, model_seed, source=name,
                             lum_max=float(getattr(source, "lum_max", 1.0)))
    readout, readout_sources = resolve_readout(settings)
    chain = SensorChain(model, readout, model_seed)  # the model itself when readout is all off
    meta = {"gs2e_version": __version__, "config": settings.as_dict(), "seed": model_seed,
            "source": name, **info, **(extra_meta or {}),
            **(source.metadata() if hasattr(source, "metadata") else {})}
    meta.update(model.describe(info["theta_on_nominal"]))
    meta["readout"] = {"values": dataclasses.asdict(readout), "sources": readout_sources}
    acc = StatsAccumulator(shape, name=name)
    span_us = getattr(source, "duration_us", None)
    with atomic_dir(out_dir) as tmp:
        with ExitStack() as stack:
            hw = stack.enter_context(H5EventWriter(tmp / "events.h5", W, H, int(t_first),
                                                   settings.compression))
            tw = (stack.enter_context(TextEventWriter(tmp / "events.txt", settings.text_polarity))
                  if settings.write_text else None)
            cws = [stack.enter_context(ContainerWriter(tmp / f"events{CONTAINERS[kind]}", kind, W, H))
                   for kind in settings.containers]
            pv = None
            if settings.preview:
                pw = stack.enter_context(PreviewWriter(tmp / "preview.mp4", shape,
                                                       settings.preview_fps))
                pv = _PreviewWindows(pw, int(t_first), int(round(settings.preview_window_ms * 1000)))
            bar = stack.enter_context(progress(None, desc=f"events {name}", unit="ms",
                                               total=round(span_us / 1000) if span_us else None))
            chain.start(int(t_first), f_first)

            clock = dict.fromkeys(("source_s", "model_s", "stats_s", "write_s"), 0.0)

            def emit(ev: Events, horizon: int | None) -> None:
                a = time.perf_counter()
                acc.update(ev)
                b = time.perf_counter()
                hw.append(ev)
                if tw:
                    tw.append(ev)
                for cw in cws:
                    cw.append(ev)
                if pv:
                    pv.add(ev, horizon, source.luminance)
                clock["stats_s"] += b - a
                clock["write_s"] += time.perf_counter() - b

            t_last = _run_chain(source, chain, emit, bar, int(t_first), clock)
            emit(chain.flush(), None)
            if pv:
                pv.finish(source.luminance)
            timings["simulate_s"] = time.perf_counter() - t_start
            timings.update(clock)
            md = _write_attrs(hw, model, chain, meta, settings.model, model_seed)
        timings["close_s"] = time.perf_counter() - t_start - timings["simulate_s"]
        if settings.write_npz:
            ev_all, _ = read_h5(tmp / "events.h5")
            write_npz(tmp / "events.npz", ev_all, W, H)
        dur_us = float(t_last - t_first)
        stats = acc.result(duration_us=dur_us)
        sst = getattr(source, "stats", None)
        sampling = dict(sst.__dict__) if sst is not None else {}
        pixel_samples = sampling.pop("pixel_samples", md["n_frames"] * H * W)
        dur_s = dur_us * 1e-6
        stats.update(n_frames=md["n_frames"], tile_intervals=model.intervals, threads=threads,
                     model=settings.model, preset=model.config_preset(settings),
                     theta_on=info["theta_on_nominal"], theta_off=info["theta_off_nominal"],
                     sampling_mode=source.sc.mode if hasattr(source, "sc") else "frames",
                     pixel_samples=int(pixel_samples),
                     pixel_samples_per_s=pixel_samples / dur_s if dur_s > 0 else None,
                     simulate_s_per_s=timings["simulate_s"] / dur_s if dur_s > 0 else None,
                     **{f"sampling_{k}": v for k, v in sampling.items()}, **timings)
        from gs2e.metrics.table import write_metrics
        row = {k: v for k, v in stats.items() if not isinstance(v, (dict, list))}
        write_metrics(tmp / "stats.parquet", row)  # NaN (not computable) -> null
        write_json_atomic(tmp / "stats.json", {"stats": stats, "metadata": json.loads(
            json.dumps(meta, default=lambda o: o.item() if isinstance(o, np.generic) else str(o)))})
    log.info("events: %s, %.3f s simulated (%dx%d) -> %d events (%.3f Mev/s, ON %.2f) in %.2f s",
             stats["sampling_mode"], dur_us * 1e-6, W, H, stats["n_events"], stats["rate_meps"],
             stats["on_fraction"] if stats["n_events"] else float("nan"), timings["simulate_s"])
    return stats
