"""Statistics of event streams and noise calibration from real recordings."""

from __future__ import annotations

import numpy as np
from numba import njit

from gs2e.common.errors import InputError
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
    iei = per_pixel_intervals(ev, W, pix)[1] * 1e-3
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


def per_pixel_intervals(ev: Events, W: int, pix: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Intervals between consecutive events of the same pixel (either polarity).

    Returns (pixel, iei_us): int64 arrays, the pixel index y * W + x of each
    interval and its length in us, grouped by pixel in time order. ``ev`` is
    time-sorted; ``pix`` (its pixel indices) may be passed when already computed.
    """
    if pix is None:
        pix = ev.y.astype(np.int64) * W + ev.x.astype(np.int64)
    order = np.argsort(pix, kind="stable")  # time-sorted input: stable keeps time order per pixel
    ps, ts = pix[order], ev.t.astype(np.int64)[order]
    same = ps[1:] == ps[:-1]
    return ps[1:][same], np.diff(ts)[same]


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


def calibrate_noise(ev: Events, shape: tuple[int, int], window_us: int = 10000,
                    n_blocks: int = 20, n_boot: int = 1000, refractory_quantile: float = 1e-4,
                    seed: int = 0) -> dict:
    """Background-activity rate, ON/OFF balance and refractory period of a real
    recording, each with a 95 % interval.

    Parameters
    ----------
    ev : Events
        Time-sorted events (t in us).
    shape : (height, width)
        Sensor size in pixels.
    window_us : int
        Support window of the background-activity (BA) criterion, us.
    n_blocks : int
        Equal time blocks of the BA-rate bootstrap.
    n_boot : int
        Bootstrap resamples (BA rate over blocks, refractory period over pixels).
    refractory_quantile : float
        Quantile of the inter-event intervals taken as their low-side cutoff.
    seed : int
        Seed of the bootstraps (the result is deterministic).

    Returns
    -------
    dict
        ``ba_rate_hz`` (isolated events per pixel per second) with
        ``ba_rate_ci95_hz`` (block bootstrap) and ``ba_rate_poisson_ci95_hz``
        (counting noise only); ``ba_on_fraction`` / ``on_fraction`` (BA / all
        events) with Wilson intervals ``*_ci95``; ``refractory_us`` with
        ``refractory_ci95_us``, ``iei_min_us``, ``n_iei``; ``isolated_fraction``,
        ``window_us``, ``duration_s``, the method parameters, and ``suggested``
        gs2e config values (shot_noise_rate_hz, shot_noise_on_fraction,
        refractory_us). Values that cannot be computed are NaN.

    Notes
    -----
    Background activity: events with no event in their 8-neighbourhood within
    +-``window_us`` (the usual BA-filter criterion), counted over all pixels
    and the recording's span. It is an upper bound on sensor noise when the
    scene itself has sparse isolated activity. Its interval comes from a
    bootstrap over ``n_blocks`` equal time blocks (resampling blocks with
    replacement, 2.5 / 97.5 percentiles of the mean rate): scene activity
    varies in time, so it is wider than the Poisson interval of the count.

    ON/OFF balance: the fraction of ON events with a Wilson score interval,
    which treats events as independent (right for BA events; too narrow for
    all events, where edges fire in correlated bursts).

    Refractory period: the low-side cutoff of the per-pixel inter-event-interval
    (IEI) distribution, i.e. the ``refractory_quantile`` quantile of the
    intervals between consecutive events of the same pixel (either polarity),
    pooled over pixels: no pixel fires again sooner than its refractory period,
    and a low quantile rather than the minimum ignores a few stray intervals
    (it lies ~q / rate above the cutoff: ~4 us for q = 1e-4 at 40 Hz per pixel).
    Its interval comes from a bootstrap over pixels (resampling pixels with
    replacement with all their intervals). It is an upper bound on the
    refractory period: a sensor with frame-like readout (DVXplorer's ~200 us
    scan) shows its readout period instead.
    """
    H, W = shape
    n = len(ev)
    nan = float("nan")
    dur_s = float(ev.t[-1] - ev.t[0]) * 1e-6 if n > 1 else 0.0
    out = {"ba_rate_hz": nan, "ba_rate_ci95_hz": [nan, nan], "ba_rate_poisson_ci95_hz": [nan, nan],
           "ba_on_fraction": nan, "ba_on_fraction_ci95": [nan, nan],
           "on_fraction": nan, "on_fraction_ci95": [nan, nan],
           "refractory_us": nan, "refractory_ci95_us": [nan, nan], "iei_min_us": nan, "n_iei": 0,
           "isolated_fraction": nan, "n_isolated": 0, "window_us": int(window_us),
           "duration_s": dur_s, "n_blocks": int(n_blocks), "n_boot": int(n_boot),
           "refractory_quantile": float(refractory_quantile)}
    if n == 0 or dur_s <= 0:
        out["suggested"] = {}
        return out
    rng = np.random.default_rng(seed)
    t = ev.t.astype(np.int64)
    iso = _isolated(t, ev.x, ev.y, H, W, int(window_us))
    n_iso = int(iso.sum())
    ba_rate = n_iso / (H * W) / dur_s
    # BA rate per time block -> bootstrap of the mean over blocks
    block = np.minimum(((t[iso] - t[0]) * n_blocks) // max(int(t[-1] - t[0]), 1), n_blocks - 1)
    rates = np.bincount(block, minlength=n_blocks) / (H * W) / (dur_s / n_blocks)
    boot = rates[rng.integers(0, n_blocks, (n_boot, n_blocks))].mean(axis=1)
    n_on = int(ev.p.sum())
    n_ba_on = int(ev.p[iso].sum())
    ref, ref_ci, iei_min, n_iei = _refractory(ev, W, refractory_quantile, n_boot, rng)
    out.update(
        ba_rate_hz=float(ba_rate),
        ba_rate_ci95_hz=[float(v) for v in np.percentile(boot, [2.5, 97.5])],
        ba_rate_poisson_ci95_hz=[v / (H * W) / dur_s for v in _poisson_ci95(n_iso)],
        ba_on_fraction=n_ba_on / n_iso if n_iso else nan,
        ba_on_fraction_ci95=_wilson95(n_ba_on, n_iso),
        on_fraction=n_on / n, on_fraction_ci95=_wilson95(n_on, n),
        refractory_us=ref, refractory_ci95_us=ref_ci, iei_min_us=iei_min, n_iei=n_iei,
        isolated_fraction=n_iso / n, n_isolated=n_iso)
    out["suggested"] = {"shot_noise_rate_hz": out["ba_rate_hz"],
                        "shot_noise_on_fraction": out["ba_on_fraction"] if n_iso else 0.5,
                        "refractory_us": ref}
    return out


def _wilson95(k: int, n: int) -> list[float]:
    """Wilson score 95 % interval of a binomial fraction k / n."""
    if n == 0:
        return [float("nan"), float("nan")]
    z = 1.959963984540054
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [float(centre - half), float(centre + half)]


def _poisson_ci95(k: int) -> list[float]:
    """Exact (Garwood) 95 % interval of a Poisson mean given the count k."""
    from scipy.stats import chi2

    lo = 0.0 if k == 0 else chi2.ppf(0.025, 2 * k) / 2
    return [float(lo), float(chi2.ppf(0.975, 2 * k + 2) / 2)]


def _refractory(ev: Events, W: int, q: float, n_boot: int, rng) -> tuple[float, list[float], float, int]:
    """(quantile-q IEI in us, its 95 % pixel-bootstrap interval, minimum IEI, number of IEIs)."""
    nan = float("nan")
    owner, iei = per_pixel_intervals(ev, W)
    if iei.size == 0:
        return nan, [nan, nan], nan, 0
    srt = np.argsort(iei, kind="stable")
    iei_sorted = iei[srt]
    # each pixel's IEIs enter a resample as often as the pixel is drawn
    pixels, owner_idx = np.unique(owner[srt], return_inverse=True)
    n_per_pixel = np.bincount(owner_idx, minlength=pixels.size)
    value = float(np.quantile(iei_sorted, q, method="inverted_cdf"))
    # a low quantile lies among the shortest intervals: cumulate those only
    # (all of them where a resample's quantile falls further out)
    m = min(iei.size, max(1000, int(50 * q * iei.size)))
    boot = np.empty(n_boot)
    for b in range(n_boot):
        draws = np.bincount(rng.integers(0, pixels.size, pixels.size), minlength=pixels.size)
        target = q * float(draws @ n_per_pixel)
        cw = np.cumsum(draws[owner_idx[:m]])
        if cw[-1] < target:
            cw = np.cumsum(draws[owner_idx])
        boot[b] = iei_sorted[np.searchsorted(cw, target, side="left")]
    return value, [float(v) for v in np.percentile(boot, [2.5, 97.5])], float(iei_sorted[0]), int(iei.size)


def sensor_preset(cal: dict, name: str, shape: tuple[int, int], source: str,
                  size_source: str | None = None, still: dict | None = None) -> dict:
    """A custom sensor preset from :func:`calibrate_noise`'s result.

    Layout (what :func:`write_sensor_preset` writes, one mapping per value)::

        name: <name>
        width:  {value: <pixels>, source: header of <file>}
        height: {value: <pixels>, source: header of <file>}
        shot_noise_rate_hz:     {value, ci95: [low, high], method, source: measured from <file>}
        shot_noise_on_fraction: {value, ci95, method, source}   # of background-activity events
        refractory_us:          {value, ci95, method, source}

    With ``still`` (:func:`still_background` of the same recording), the
    background comes from the still region instead: ``leak_rate_hz``,
    ``shot_noise_rate_hz``, ``shot_noise_on_fraction``, ``hot_pixel_fraction``,
    ``hot_pixel_rate_hz``, ``hot_pixel_on_fraction`` (no interval: method and
    source only).

    The keys are the ``events`` config keys they set: the file is a sensor for
    ``events.sensor: custom`` / ``events.sensor_file``
    (:func:`gs2e.events.sensors.load_sensor_file`); the background-activity
    rate is what the shot-noise model emits.
    """
    H, W = shape
    measured = f"measured from {source}"

    def sig(v: float) -> float:  # 4 significant digits: the intervals are wider
        return float(f"{v:.4g}")

    out = {
        "name": name,
        "width": {"value": int(W), "source": size_source or f"header of {source}"},
        "height": {"value": int(H), "source": size_source or f"header of {source}"},
        "shot_noise_rate_hz": {
            "value": sig(cal["ba_rate_hz"]), "ci95": [sig(v) for v in cal["ba_rate_ci95_hz"]],
            "method": f"events without an 8-neighbour event within +-{cal['window_us']} us, per pixel "
                      f"per second; 95 % interval: bootstrap over {cal['n_blocks']} time blocks",
            "source": measured},
        "shot_noise_on_fraction": {
            "value": sig(cal["ba_on_fraction"]), "ci95": [sig(v) for v in cal["ba_on_fraction_ci95"]],
            "method": "ON fraction of the background-activity events; 95 % interval: Wilson",
            "source": measured},
        "refractory_us": {
            "value": sig(cal["refractory_us"]), "ci95": [sig(v) for v in cal["refractory_ci95_us"]],
            "method": f"{cal['refractory_quantile']:g} quantile of the per-pixel inter-event "
                      "intervals (their low-side cutoff; an upper bound); 95 % interval: bootstrap "
                      "over pixels",
            "source": measured},
    }
    if still is not None:
        region = (f"the still region of {source} (APS std < {still['still_std']:g} over the recording, "
                  f"{still['erode_px']} px from any moving pixel; {still['still_fraction']:.0%} of the "
                  f"pixels, {still['duration_s']:.2f} s)")
        how = {"leak_rate_hz": "ON events of the background less the shot noise's (gs2e.events.stats."
                               "still_background)",
               "shot_noise_rate_hz": "twice the OFF rate, scaled to gs2e's 2 (1 - L) at the region's "
                                     f"mean APS brightness {still['lum_mean']:.3f}",
               "shot_noise_on_fraction": "shot noise taken as balanced (all excess ON events are leak)",
               "hot_pixel_fraction": f"still pixels firing over {still['hot_factor']:g} x the others' "
                                     "mean rate",
               "hot_pixel_rate_hz": "mean rate of those pixels",
               "hot_pixel_on_fraction": "ON fraction of their events (0.5 when there are none)"}
        lit = np.isfinite(still["leak_light_rate_hz"])  # the leak as a line in brightness
        if lit:
            how["leak_rate_hz"] = "the leak at zero brightness (gs2e.events.stats.leak_against_brightness)"
            how["leak_light_rate_hz"] = ("the leak's growth per unit of APS brightness, fitted to the "
                                         "brightness bins (gs2e.events.stats.leak_against_brightness)")
        vals = {"leak_rate_hz": still["leak_dark_rate_hz"] if lit else still["leak_rate_hz"],
                **({"leak_light_rate_hz": still["leak_light_rate_hz"]} if lit else {}),
                "shot_noise_rate_hz": still["shot_noise_rate_hz"],
                "shot_noise_on_fraction": still["shot_noise_on_fraction"],
                "hot_pixel_fraction": still["hot_fraction"], "hot_pixel_rate_hz": still["hot_rate_hz"],
                "hot_pixel_on_fraction": (still["hot_on_fraction"] if still["n_hot"] else 0.5)}
        for k, v in vals.items():
            out[k] = {"value": sig(float(v)), "method": how[k], "source": f"measured in {region}"}
    return out


def write_sensor_preset(path, preset: dict) -> None:
    """Write :func:`sensor_preset`'s dict as YAML, atomically (any NaN -> null)."""
    import yaml

    from gs2e.common.atomic import atomic_file, json_safe

    head = ("# gs2e sensor preset measured from a real recording (gs2e events-stats --write-preset).\n"
            "# Each value: value, ci95 = [low, high] (95 % interval), method, source.\n")
    with atomic_file(path, "w") as fh:
        fh.write(head + yaml.safe_dump(json_safe(preset), sort_keys=False, width=100,
                                          default_flow_style=None))  # [low, high] on one line


# "no event yet" in StatsAccumulator.last: times may be negative (any t_offset)
NO_EVENT = np.iinfo(np.int64).min


@njit(cache=True, nogil=True)
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


# ---------------------------------------------------------------- still background
def still_background(ev: Events, shape: tuple[int, int], aps: np.ndarray, still_std: float = 0.01,
                     erode_px: int = 2, hot_factor: float = 10.0, n_bins: int = 5,
                     mask: np.ndarray | None = None) -> dict:
    """Background activity and hot pixels of a recording's still region,
    against the APS brightness.

    Parameters
    ----------
    ev : time-sorted events (t in us) of a sensor of ``shape`` (H, W).
    aps : (N, H, W) APS frames in [0, 1] (linear) over the recording.
    still_std : a pixel is still where its APS values' std over the frames
        is below this, and so are those within ``erode_px`` pixels.
    hot_factor : a still pixel is hot where its rate exceeds this many times
        the mean rate of the other still pixels (iterated to a fixed point;
        a Poisson count at the background's mean reaches it with negligible
        probability at the rates of real sensors).
    n_bins : brightness bins (quantiles of the still pixels' mean APS value).
    mask : (H, W) bool still region to use instead (e.g. a real recording's,
        to measure a simulation over the same pixels).

    Returns
    -------
    dict: ``duration_s``; ``still_fraction``; ``ba_rate_hz`` (events per
    non-hot still pixel per second) and ``ba_on_fraction``; ``hot_fraction``
    (of the still pixels), ``hot_rate_hz`` (mean per hot pixel),
    ``hot_on_fraction``, ``n_hot``; ``by_brightness``: per bin
    {lum_lo, lum_hi, lum_mean, n_pixels, ba_rate_hz, ba_on_fraction}; and
    gs2e's noise model fitted by polarity: leak events are ON at a constant
    rate, shot noise half ON at ``shot 2 (1 - L)``, so the OFF events are half
    the shot noise at the region's mean brightness ``lum_mean``:
    ``leak_rate_hz``, ``shot_noise_rate_hz``, ``shot_noise_on_fraction`` (0.5).
    ``_mask`` and ``_hot`` (arrays) are the pixels used.
    """
    import cv2

    H, W = shape
    aps = np.asarray(aps, np.float64)
    if aps.ndim != 3 or aps.shape[1:] != (H, W):
        raise InputError(f"APS frames of shape {aps.shape} do not match the sensor {W}x{H}")
    if mask is None:
        moving = (aps.std(axis=0) >= still_std).astype(np.uint8)
        if erode_px > 0:
            k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
            moving = cv2.dilate(moving, k)
        mask = moving == 0
    dur_s = (int(ev.t[-1]) - int(ev.t[0])) * 1e-6 if len(ev) > 1 else float("nan")
    pix = ev.y.astype(np.int64) * W + ev.x.astype(np.int64)
    counts = np.bincount(pix, minlength=H * W).reshape(H, W).astype(np.float64)
    on = np.bincount(pix, weights=ev.p.astype(np.float64), minlength=H * W).reshape(H, W)
    rate = counts / dur_s
    hot = np.zeros((H, W), bool)
    for _ in range(20):
        base = rate[mask & ~hot]
        mean = float(base.mean()) if base.size else 0.0
        new = mask & (rate > hot_factor * max(mean, 1.0 / dur_s))
        if np.array_equal(new, hot):
            break
        hot = new
    bg = mask & ~hot
    lum = aps.mean(axis=0)
    out = {"duration_s": dur_s, "still_fraction": float(mask.mean()), "still_std": still_std,
           "erode_px": erode_px, "hot_factor": hot_factor,
           "ba_rate_hz": float(rate[bg].mean()) if bg.any() else float("nan"),
           "ba_on_fraction": float(on[bg].sum() / counts[bg].sum()) if counts[bg].sum() else float("nan"),
           "n_hot": int(hot.sum()), "hot_fraction": float(hot.sum() / max(1, mask.sum())),
           "hot_rate_hz": float(rate[hot].mean()) if hot.any() else 0.0,
           "hot_on_fraction": float(on[hot].sum() / counts[hot].sum()) if counts[hot].sum() else float("nan")}
    bins = []
    if bg.any():
        edges = np.unique(np.quantile(lum[bg], np.linspace(0, 1, n_bins + 1)))
        which = np.clip(np.searchsorted(edges, lum, side="right") - 1, 0, len(edges) - 2)
        for b in range(len(edges) - 1):
            sel = bg & (which == b)
            if not sel.any():
                continue
            n_ev = counts[sel].sum()
            bins.append({"lum_lo": float(edges[b]), "lum_hi": float(edges[b + 1]),
                         "lum_mean": float(lum[sel].mean()), "n_pixels": int(sel.sum()),
                         "ba_rate_hz": float(rate[sel].mean()),
                         "ba_on_fraction": float(on[sel].sum() / n_ev) if n_ev else float("nan")})
    out["by_brightness"] = bins
    # gs2e's noise model: leak events (ON, constant rate) plus shot noise at
    # shot 2 (1 - L), half ON: the OFF events are half the shot noise
    ba, q = out["ba_rate_hz"], out["ba_on_fraction"]
    if np.isfinite(ba) and np.isfinite(q):
        shot_emitted = min(ba, 2.0 * ba * (1.0 - q))
        lum_bar = float(lum[bg].mean())
        out.update(lum_mean=lum_bar, leak_rate_hz=float(ba - shot_emitted),
                   shot_noise_rate_hz=float(shot_emitted / (2.0 * (1.0 - lum_bar))) if lum_bar < 1 else 0.0,
                   shot_noise_on_fraction=0.5)
    else:
        out.update(lum_mean=float("nan"), leak_rate_hz=float("nan"), shot_noise_rate_hz=float("nan"),
                   shot_noise_on_fraction=float("nan"))
    out.update(leak_against_brightness(bins, out["shot_noise_rate_hz"]))
    out["_mask"], out["_hot"] = mask, hot
    return out


def leak_against_brightness(bins: list[dict], shot_noise_rate_hz: float) -> dict:
    """The leak as a line in brightness, leak(L) = dark + light L, fitted
    to the brightness bins of :func:`still_background` (their rate less the
    shot noise's ``shot 2 (1 - L)``; least squares weighted by each bin's
    pixels; the slope held >= 0). The leak grows with the light through
    parasitic photocurrent (Nozaki and Delbruck, IEEE TED 2017).

    Returns {``leak_dark_rate_hz``, ``leak_light_rate_hz``} (Hz per pixel,
    and per pixel per unit of linear brightness); NaN with under two bins."""
    if len(bins) < 2 or not np.isfinite(shot_noise_rate_hz):
        return {"leak_dark_rate_hz": float("nan"), "leak_light_rate_hz": float("nan")}
    L = np.array([b["lum_mean"] for b in bins])
    w = np.array([b["n_pixels"] for b in bins], np.float64)
    y = np.array([b["ba_rate_hz"] for b in bins]) - shot_noise_rate_hz * 2.0 * np.clip(1.0 - L, 0.0, None)
    Lm, ym = np.average(L, weights=w), np.average(y, weights=w)
    var = np.average((L - Lm) ** 2, weights=w)
    slope = max(0.0, float(np.average((L - Lm) * (y - ym), weights=w) / var)) if var > 0 else 0.0
    return {"leak_dark_rate_hz": float(ym - slope * Lm), "leak_light_rate_hz": slope}
