"""Pure plotting functions of the report.

Figures are built with :class:`matplotlib.figure.Figure` directly (Agg canvas,
no pyplot state), so the functions are safe in any process and thread.
Every function takes arrays or tables and returns a Figure, an image array or
PNG bytes; none reads files.
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from gs2e.events.models import Events
from gs2e.events.represent import event_frame
from gs2e.events.stats import StatsAccumulator
from gs2e.io.images import encode_png, resize_image, scaled_size

# Colours of the event previews (as in gs2e.events.represent.render_overlay).
ON_RGB = (40, 120, 255)
OFF_RGB = (255, 40, 40)


def new_figure(width_in: float, height_in: float) -> Figure:
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def fig_png(fig: Figure, dpi: int = 90) -> bytes:
    """PNG bytes of a figure (metadata stripped so equal figures give equal bytes)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata={"Software": None})
    return buf.getvalue()


def image_png(rgb: np.ndarray, max_side_px: int | None = None) -> bytes:
    """PNG bytes of a uint8 (H, W, 3) image, shrunk so its longer side is at
    most ``max_side_px`` pixels (None: full size)."""
    if max_side_px is not None:
        rgb = resize_image(rgb, scaled_size(rgb.shape[1], rgb.shape[0], 1, max_side_px))
    return encode_png(np.ascontiguousarray(rgb))


# ---------------------------------------------------------------- training
def speed_error_figure(curves: dict[str, pd.DataFrame]) -> Figure | None:
    """Held-out PSNR and SSIM against training wall time, one line per scene.

    ``curves``: scene -> table with columns train_time_s, psnr (dB), ssim
    (rows in training order). Returns None when there is no curve at all.
    """
    curves = {k: v for k, v in curves.items() if v is not None and len(v)}
    if not curves:
        return None
    fig = new_figure(10, 3.8)
    ax_p, ax_s = fig.subplots(1, 2)
    for i, (scene, c) in enumerate(sorted(curves.items())):
        kw = dict(marker="o", ms=3, lw=1.4, color=f"C{i % 10}", label=scene)
        ax_p.plot(c["train_time_s"], c["psnr"], **kw)
        if "ssim" in c:
            ax_s.plot(c["train_time_s"], c["ssim"], **kw)
    ax_p.set_xlabel("training wall time (s)")
    ax_p.set_ylabel("held-out PSNR (dB)")
    ax_s.set_xlabel("training wall time (s)")
    ax_s.set_ylabel("held-out SSIM (1 = identical)")
    ax_p.set_title("quality against training time")
    ax_s.set_title("structural similarity against training time")
    for ax in (ax_p, ax_s):
        ax.grid(alpha=0.3)
    if len(curves) <= 12:
        ax_p.legend(fontsize=8, title="scene")
    return fig


# ---------------------------------------------------------------- stage costs
BENCH_PANELS = (("s", "wall time (s)"), ("cpu_time", "CPU time (s)"),
                ("max_rss", "peak memory, max RSS (MB)"))


def benchmark_figure(bench: pd.DataFrame, title: str = "") -> Figure | None:
    """Horizontal bars of wall time, CPU time and peak memory per workflow job.

    ``bench``: one row per job with columns ``rule`` (job name, e.g.
    ``render_base_medium``) and Snakemake's benchmark columns s (seconds),
    cpu_time (seconds), max_rss (MB); non-numeric cells are missing. Returns
    None for an empty table.
    """
    if bench is None or len(bench) == 0:
        return None
    b = bench.reset_index(drop=True)
    y = np.arange(len(b))
    fig = new_figure(11, 0.8 + 0.28 * len(b))
    axes = fig.subplots(1, len(BENCH_PANELS), sharey=True)
    for ax, (col, label) in zip(axes, BENCH_PANELS):
        v = pd.to_numeric(b[col], errors="coerce") if col in b else pd.Series(np.nan, index=b.index)
        # a log axis and the value at each bar: training takes 100x the short jobs,
        # whose bars would otherwise be slivers
        pos = v[np.isfinite(v) & (v > 0)]
        floor = float(pos.min()) / 3 if len(pos) else 0.1
        ax.barh(y, v.fillna(floor).clip(lower=floor) - floor, left=floor,
                color=["C0" if np.isfinite(x) else "0.8" for x in v])
        ax.set_xscale("log")
        for yi, x in zip(y, v):
            ax.text(x if np.isfinite(x) and x > 0 else floor, yi,
                    f" {x:.3g}" if np.isfinite(x) else " missing", va="center", fontsize=7,
                    color="0.2" if np.isfinite(x) else "0.4")
        ax.set_xlim(floor, (float(pos.max()) if len(pos) else 1.0) * 4)
        ax.set_xlabel(label + ", log scale")
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, b["rule"].astype(str), fontsize=8)
    axes[0].invert_yaxis()
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


# ---------------------------------------------------------------- events
@dataclass
class EventSeries:
    """Event statistics of one stream, ready to plot.

    t_s: (n,) bin centres, seconds from the first event; rate_hz: (n,) events
    per pixel per second in each bin; iei_edges_ms: (m + 1,) log-spaced bin
    edges of per-pixel inter-event intervals (ms); iei_density: (m,) fraction
    of intervals per decade of interval (integrates to 1 over log10 ms);
    stats: :func:`gs2e.events.stats.event_stats`-style summary row.
    """

    label: str
    t_s: np.ndarray
    rate_hz: np.ndarray
    iei_edges_ms: np.ndarray
    iei_density: np.ndarray
    stats: dict
    real: bool = False


def event_rate(t_us: np.ndarray, n_pixels: int, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Event rate over time in ``n_bins`` equal bins tiling [t_first, t_last]
    exactly (no partial bin at the end): (bin centres in s from the first
    event, events per pixel per second). ``t_us`` sorted microseconds; empty
    input gives empty arrays."""
    t = np.asarray(t_us, dtype=np.int64)
    if t.size == 0:
        return np.zeros(0), np.zeros(0)
    span_us = float(t[-1] - t[0]) + 1.0  # +1: the last event's microsecond
    n_bins = max(1, int(n_bins))
    bin_us = span_us / n_bins
    idx = np.minimum(((t - t[0]) / bin_us).astype(np.int64), n_bins - 1)
    counts = np.bincount(idx, minlength=n_bins)
    centres_s = (np.arange(n_bins) + 0.5) * bin_us * 1e-6
    return centres_s, counts / (n_pixels * bin_us * 1e-6)


def iei_histogram(acc: StatsAccumulator, bins_per_decade: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel inter-event-interval histogram from a :class:`StatsAccumulator`
    (whose fine log-spaced histogram is regrouped to ``bins_per_decade``).

    Returns (edges in ms (m + 1,), density (m,) in fraction per decade),
    trimmed to the bins between the first and last non-empty one; empty arrays
    when the stream has no interval.
    """
    fine_w = 0.005  # ln-width of the accumulator's bins (1 us .. 1e10 us)
    group = max(1, int(round(math.log(10.0) / bins_per_decade / fine_w)))
    h = acc.hist
    pad = (-len(h)) % group
    coarse = np.concatenate([h, np.zeros(pad, h.dtype)]).reshape(-1, group).sum(1)
    total = coarse.sum()
    if total == 0:
        return np.zeros(0), np.zeros(0)
    nz = np.flatnonzero(coarse)
    lo, hi = nz[0], nz[-1] + 1
    edges_us = np.exp(acc.log_lo + np.arange(lo, hi + 1) * group * fine_w)
    dlog10 = group * fine_w / math.log(10.0)
    return edges_us * 1e-3, coarse[lo:hi] / total / dlog10


def event_series(ev: Events, shape: tuple[int, int], label: str, real: bool = False,
                 rate_bins: int = 60, min_bin_us: float = 1000.0) -> EventSeries:
    """Rate-over-time and inter-event-interval statistics of one stream.

    ``shape`` = (H, W) of the sensor; the rate uses ``rate_bins`` equal bins
    over the stream, fewer if they would be shorter than ``min_bin_us``.
    """
    H, W = shape
    acc = StatsAccumulator((H, W), name=label)
    acc.update(ev)
    span = float(ev.t[-1] - ev.t[0]) + 1.0 if len(ev) else 0.0
    t_s, rate = event_rate(ev.t, H * W, min(rate_bins, max(1, int(span // min_bin_us))))
    edges, dens = iei_histogram(acc)
    return EventSeries(label, t_s, rate, edges, dens, acc.result(), real)


def event_stats_figure(series: list[EventSeries], title: str = "") -> Figure | None:
    """Two panels: event rate per pixel over time, and the per-pixel
    inter-event-interval distribution (log-spaced bins, normalised). Real
    recordings are drawn black and dashed. None when ``series`` is empty."""
    if not series:
        return None
    fig = new_figure(11, 3.8)
    ax_r, ax_i = fig.subplots(1, 2)
    k = 0
    for s in series:
        if s.real:
            kw = dict(color="k", ls="--", lw=1.6)
        else:
            kw = dict(color=f"C{k % 10}", lw=1.4)
            k += 1
        med = s.stats.get("iei_median_ms", float("nan"))
        lab = f"{s.label} (median {med:.3g} ms)" if np.isfinite(med) else s.label
        if len(s.t_s):
            ax_r.step(s.t_s, s.rate_hz, where="mid", label=s.label, **kw)
        if len(s.iei_density):
            ax_i.stairs(s.iei_density, s.iei_edges_ms, label=lab, **kw)
    ax_r.set_xlabel("time from first event (s)")
    ax_r.set_ylabel("event rate per pixel (events/pixel/s)")
    ax_r.set_title("event rate over time")
    ax_i.set_xscale("log")
    ax_i.set_xlabel("per-pixel inter-event interval (ms)")
    ax_i.set_ylabel("density (fraction of intervals per decade)")
    ax_i.set_title("inter-event intervals")
    for ax in (ax_r, ax_i):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def preview_window_us(ev: Events, frame_t_us: np.ndarray | None,
                      window_us: float) -> tuple[int, int, int | None]:
    """Window of an event preview: ``window_us`` long, centred on the frame
    nearest the middle of the stream (or on the middle itself without frames)
    and shifted to lie within the stream. Returns (t0, t1, frame index or None).
    """
    t_first, t_last = int(ev.t[0]), int(ev.t[-1])
    mid = 0.5 * (t_first + t_last)
    idx = None
    centre = mid
    if frame_t_us is not None and len(frame_t_us):
        ft = np.asarray(frame_t_us, dtype=np.int64)
        idx = int(np.argmin(np.abs(ft - mid)))
        centre = float(ft[idx])
    half = 0.5 * window_us
    t0 = int(round(min(max(centre - half, t_first), max(t_last + 1 - window_us, t_first))))
    t1 = int(round(t0 + window_us))
    return t0, t1, idx


def event_preview(ev: Events, shape: tuple[int, int], t0_us: int, t1_us: int,
                  background: np.ndarray | None = None) -> np.ndarray:
    """ON/OFF accumulation image of the events with t0 <= t < t1 (us).

    Pixels with more ON than OFF events are blue, more OFF red, over the
    ``background`` uint8 RGB (H, W, 3) frame dimmed to 60 % (mid grey when
    None). Returns uint8 (H, W, 3).
    """
    H, W = shape
    if background is None:
        img = np.full((H, W, 3), 128, np.uint8)
    else:
        if background.shape != (H, W, 3):
            raise ValueError(f"background {background.shape} does not match the sensor ({H}, {W}, 3)")
        img = (background.astype(np.float32) * 0.6).astype(np.uint8)
    counts = event_frame(ev, shape, t0_us, t1_us)  # [0] OFF, [1] ON
    net = counts[1].astype(np.int64) - counts[0]
    img[net > 0] = ON_RGB
    img[net < 0] = OFF_RGB
    return img


# The card's columns the dataset page draws, with their axis labels.
CARD_DISTRIBUTIONS = (("psnr_db", "held-out PSNR (dB)", False), ("ssim", "held-out SSIM", False),
                      ("gaussians", "Gaussians", True), ("events", "events (all runs)", True),
                      ("cpu_min", "CPU-min per scene", False), ("registered", "registered views", False))


def card_figure(card: pd.DataFrame) -> Figure | None:
    """Histograms across scenes of the dataset card's columns (passed scenes
    filled, failed ones outlined); None when no column has a value."""
    cols = [(c, lab, lg) for c, lab, lg in CARD_DISTRIBUTIONS
            if c in card and pd.to_numeric(card[c], errors="coerce").notna().any()]
    if not cols:
        return None
    fig = new_figure(3.0 * len(cols), 2.6)
    axes = fig.subplots(1, len(cols), squeeze=False)[0]
    ok = card["status"].eq("passed") if "status" in card else pd.Series(True, index=card.index)
    for ax, (c, label, log_x) in zip(axes, cols):
        v = pd.to_numeric(card[c], errors="coerce")
        allv = v.dropna().to_numpy(float)
        if log_x:
            allv = allv[allv > 0]
        if allv.size == 0:
            continue
        lo, hi = allv.min(), allv.max()
        bins = (np.geomspace(lo, hi * 1.0001, 9) if log_x and hi > lo else
                np.linspace(lo, hi + (1e-9 if hi == lo else 0.0), 9))
        ax.hist(v[ok].dropna(), bins=bins, color="tab:blue", label="passed")
        if (~ok).any() and v[~ok].notna().any():
            ax.hist(v[~ok].dropna(), bins=bins, histtype="step", color="tab:red", lw=1.5, label="failed")
            ax.legend(fontsize=7)
        if log_x:
            ax.set_xscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("scenes")
        ax.grid(alpha=0.3)
    return fig
