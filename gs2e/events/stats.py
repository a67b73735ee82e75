"""Statistics of event streams and noise calibration from real recordings."""

from __future__ import annotations

import numpy as np
from numba import njit

from gs2e.events.models import Events


def event_stats(ev: Events, shape: tuple[int, int], duration_us: float | None = None,
                name: str = "") -> dict:
    """One row of statistics of an event stream.

    Keys: n_events, duration_s, rate_meps (M events/s), on_fraction,
    density_mean_hz (events per pixel per second over all pixels),
    density_median_active_hz / density_p99_hz (over pixels with >= 1 event),
    active_pixel_fraction, iei_median_ms / iei_mean_ms / iei_p10_ms / iei_p90_ms
    (per-pixel inter-event intervals, all pixels pooled), n_iei.
    ``duration_us`` defaults to the span of the events. Values that cannot be
    computed (no events, no intervals, zero duration) are NaN; writers store
    them as null.
    """
    H, W = shape
    n = len(ev)
    if duration_us is None:
        duration_us = float(ev.t[-1] - ev.t[0]) if n > 1 else 0.0
    dur_s = duration_us * 1e-6
    row = {"name": name, "n_events": n, "width": W, "height": H, "duration_s": dur_s}
    nan = float("nan")
    if n == 0 or dur_s <= 0:
        row.update(rate_meps=nan if dur_s <= 0 else 0.0, on_fraction=nan, density_mean_hz=0.0,
                   density_median_active_hz=nan, density_p99_hz=nan, active_pixel_fraction=0.0,
                   iei_median_ms=nan, iei_mean_ms=nan, iei_p10_ms=nan, iei_p90_ms=nan, n_iei=0)
        return row
    pix = ev.y.astype(np.int64) * W + ev.x.astype(np.int64)
    counts = np.bincount(pix, minlength=H * W)
    active = counts[counts > 0] / dur_s
    order = np.argsort(pix, kind="stable")  # events are time-sorted: stable keeps time order
    ps, ts = pix[order], ev.t[order]
    same = ps[1:] == ps[:-1]
    iei = np.diff(ts)[same] * 1e-3
    row.update(
        rate_meps=n / dur_s * 1e-6,
        on_fraction=float(ev.p.mean()),
        density_mean_hz=n / (H * W) / dur_s,
        density_median_active_hz=float(np.median(active)),
        density_p99_hz=float(np.percentile(counts / dur_s, 99)),
        active_pixel_fraction=float((counts > 0).mean()),
        iei_median_ms=float(np.median(iei)) if iei.size else nan,
        iei_mean_ms=float(iei.mean()) if iei.size else nan,
        iei_p10_ms=float(np.percentile(iei, 10)) if iei.size else nan,
        iei_p90_ms=float(np.percentile(iei, 90)) if iei.size else nan,
        n_iei=int(iei.size),
    )
    return row


@njit(cache=True)
def _isolated(t, x, y, H, W, window_us):
    """True for events with no event in the 8-neighbourhood (other pixels)
    within ``window_us`` before or after (a background-activity filter run
    forwards and backwards)."""
    n = t.shape[0]
    iso = np.ones(n, np.bool_)
    last = np.full((H, W), -(1 << 62), np.int64)
    for i in range(n):
        xi, yi = np.int64(x[i]), np.int64(y[i])
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if dx == 0 and dy == 0:
                    continue
                yy, xx = yi + dy, xi + dx
                if 0 <= yy < H and 0 <= xx < W and t[i] - last[yy, xx] <= window_us:
                    iso[i] = False
        last[yi, xi] = t[i]
    last[:, :] = 1 << 62
    for i in range(n - 1, -1, -1):
        xi, yi = np.int64(x[i]), np.int64(y[i])
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                if dx == 0 and dy == 0:
                    continue
                yy, xx = yi + dy, xi + dx
                if 0 <= yy < H and 0 <= xx < W and last[yy, xx] - t[i] <= window_us:
                    iso[i] = False
        last[yi, xi] = t[i]
    return iso


def calibrate_noise(ev: Events, shape: tuple[int, int], window_us: int = 10000) -> dict:
    """Background-activity rate and ON/OFF balance of a real recording.

    Events without support in their 8-neighbourhood within +-``window_us`` are
    counted as background activity (the usual BA filter criterion). Returns
    ba_rate_hz (isolated events per pixel per second), ba_on_fraction,
    on_fraction (all events), isolated_fraction, window_us, and the config
    values suggested for gs2e (shot_noise_rate_hz, shot_noise_on_fraction).
    The estimate is an upper bound on sensor noise if the scene itself has
    sparse isolated activity.
    """
    H, W = shape
    n = len(ev)
    dur_s = float(ev.t[-1] - ev.t[0]) * 1e-6 if n > 1 else 0.0
    if n == 0 or dur_s <= 0:
        return {"ba_rate_hz": float("nan"), "ba_on_fraction": float("nan"),
                "on_fraction": float("nan"), "isolated_fraction": float("nan"),
                "window_us": window_us}
    iso = _isolated(ev.t.astype(np.int64), ev.x, ev.y, H, W, int(window_us))
    n_iso = int(iso.sum())
    ba_rate = float(n_iso / (H * W) / dur_s)
    ba_on = float(ev.p[iso].mean()) if n_iso else float("nan")
    return {"ba_rate_hz": ba_rate, "ba_on_fraction": ba_on, "on_fraction": float(ev.p.mean()),
            "isolated_fraction": n_iso / n, "window_us": int(window_us), "duration_s": dur_s,
            "suggested": {"shot_noise_rate_hz": ba_rate,
                          "shot_noise_on_fraction": ba_on if n_iso else 0.5}}


# "no event yet" in StatsAccumulator.last: times may be negative (any t_offset)
NO_EVENT = np.iinfo(np.int64).min


@njit(cache=True)
def _acc_update(t, x, y, W, counts, last, hist, log_lo, inv_bw, nb, sums):
    for i in range(t.shape[0]):
        pix = np.int64(y[i]) * W + np.int64(x[i])
        counts[pix] += 1
        lt = last[pix]
        if lt != NO_EVENT:
            d = t[i] - lt
            sums[0] += d
            sums[1] += 1
            if d < 1:
                d = 1
            b = int((np.log(float(d)) - log_lo) * inv_bw)
            hist[min(max(b, 0), nb - 1)] += 1
        last[pix] = t[i]


class StatsAccumulator:
    """Streaming version of :func:`event_stats` (memory independent of the
    number of events): IEI percentiles come from a log-spaced histogram
    (1 us .. 1e4 s, 0.5 % bins), so they are exact to ~0.5 %."""

    def __init__(self, shape: tuple[int, int], name: str = ""):
        H, W = shape
        self.shape, self.name = shape, name
        self.counts = np.zeros(H * W, np.int64)
        self.last = np.full(H * W, NO_EVENT, np.int64)
        self.log_lo, self.log_hi = 0.0, np.log(1e10)
        self.nb = int(np.ceil((self.log_hi - self.log_lo) / 0.005))
        self.hist = np.zeros(self.nb, np.int64)
        self.sums = np.zeros(2, np.int64)
        self.n = self.n_on = 0
        self.t_first = self.t_last = None

    def update(self, ev: Events) -> None:
        if len(ev) == 0:
            return
        if self.t_first is None:
            self.t_first = int(ev.t[0])
        self.t_last = int(ev.t[-1])
        self.n += len(ev)
        self.n_on += int(ev.p.sum())
        _acc_update(ev.t.astype(np.int64), ev.x, ev.y, self.shape[1], self.counts, self.last,
                    self.hist, self.log_lo, 1.0 / 0.005, self.nb, self.sums)

    def _pct(self, q: float) -> float:
        c = np.cumsum(self.hist)
        if c[-1] == 0:
            return float("nan")
        b = int(np.searchsorted(c, q / 100.0 * c[-1], side="left"))
        return float(np.exp(self.log_lo + (b + 0.5) * 0.005)) * 1e-3  # ms

    def result(self, duration_us: float | None = None) -> dict:
        H, W = self.shape
        if duration_us is None:
            duration_us = float(self.t_last - self.t_first) if self.n > 1 else 0.0
        dur_s = duration_us * 1e-6
        nan = float("nan")
        row = {"name": self.name, "n_events": self.n, "width": W, "height": H, "duration_s": dur_s}
        if self.n == 0 or dur_s <= 0:
            row.update(rate_meps=nan if dur_s <= 0 else 0.0, on_fraction=nan,
                       density_mean_hz=0.0, density_median_active_hz=nan, density_p99_hz=nan,
                       active_pixel_fraction=0.0, iei_median_ms=nan, iei_mean_ms=nan,
                       iei_p10_ms=nan, iei_p90_ms=nan, n_iei=0)
            return row
        active = self.counts[self.counts > 0] / dur_s
        n_iei = int(self.sums[1])
        row.update(
            rate_meps=self.n / dur_s * 1e-6, on_fraction=self.n_on / self.n,
            density_mean_hz=self.n / (H * W) / dur_s,
            density_median_active_hz=float(np.median(active)),
            density_p99_hz=float(np.percentile(self.counts / dur_s, 99)),
            active_pixel_fraction=float((self.counts > 0).mean()),
            iei_median_ms=self._pct(50), iei_mean_ms=(self.sums[0] / n_iei * 1e-3) if n_iei else nan,
            iei_p10_ms=self._pct(10), iei_p90_ms=self._pct(90), n_iei=n_iei)
        return row
