"""The ``events`` config section as one typed object, resolved once.

:func:`event_settings` turns the validated section (a dict, as
``gs2e.config.load_section("events")`` gives it) into :class:`EventSettings`;
the stage passes that object on (models, sampling, writers) and records
:meth:`EventSettings.as_dict` in ``events.h5`` (``metadata`` -> ``config``) and
``stats.json``. Readers of an event folder (the benchmark, the exports) get it
back through :func:`read_settings` (the rest of the metadata through
:func:`read_metadata`), never by parsing the attributes themselves.
"""

from __future__ import annotations

import copy
import functools
import json
from dataclasses import dataclass, fields
from typing import Any, Mapping

from gs2e.common.errors import InputError
from gs2e.config import points_per_step


@dataclass(frozen=True)
class SamplingSettings:
    """``events.sampling``: when the renderer is sampled (times in us)."""

    mode: str                 # fixed | adaptive | tile | motion | curve
    fixed_fps: float          # fixed mode's rate; the others' first step
    bound_fraction: float     # adaptive / tile: fraction of the smallest log step per sample
    error_fraction: float     # curve: the curve's error between renders, same units
    outlier_fraction: float   # adaptive / curve: pixels allowed over the bound
    dt_min_us: int
    dt_max_us: int
    max_motion_px: float | None   # tile / motion / curve: image motion per step (px / Gaussian sigma)
    window_motion_px: float   # tile: motion over which a tile's candidate list is kept
    substeps: int             # points per step on the cubic through the renders (1: renders only; resolved)
    slopes: str               # the cubic's slopes: neighbours (Catmull-Rom) | difference (2 us) | tangent


@dataclass(frozen=True)
class EventSettings:
    """The ``events`` section, typed (see config/README.md for each key).

    Thresholds are in the model's units (ideal: log-intensity steps;
    voltmeter: normalised voltage); rates in Hz per pixel; times in us unless
    the name says otherwise. ``None`` in a noise key means "from the sensor
    preset, else 0" (:func:`gs2e.events.sensors.resolve_noise`).
    """

    sensor: str | None
    sensor_file: str | None
    sensor_fit: str
    model: str
    preset: str
    k1: float | None
    k2: float | None
    k3: float | None
    k4: float | None
    k5: float | None
    k6: float | None
    exit_law: str
    theta_on: float
    theta_off: float
    theta_sampling: str
    theta_range: tuple[float, float]
    theta_on_off_independent: bool
    theta_mismatch_sigma: float | None
    theta_mismatch_rel: float | None
    refractory_us: float | None
    leak_rate_hz: float | None
    leak_light_rate_hz: float | None
    cfa: str | None
    shot_noise_rate_hz: float | None
    shot_noise_on_fraction: float | None
    photoreceptor_cutoff_hz: float | None
    photoreceptor_dark_fraction: float | None
    hot_pixel_fraction: float | None
    hot_pixel_rate_hz: float | None
    hot_pixel_on_fraction: float | None
    readout_rate_meps: float | None
    readout_latency_us: float | None
    readout_jitter_us: float | None
    readout_queue_events: int | None
    log_eps: float
    max_duration_s: float | None
    sampling: SamplingSettings
    max_events_per_pixel: int
    seed_offset: int
    batch_frames: int
    num_threads: int
    compression: str
    write_text: bool
    text_polarity: str
    write_npz: bool
    containers: tuple[str, ...]
    preview: bool
    preview_window_ms: float
    preview_fps: float
    _section: Mapping[str, Any] = None  # the section as given (recorded as is)

    def as_dict(self) -> dict:
        """The section as it was given (a copy): what the outputs record."""
        return copy.deepcopy(dict(self._section))


@functools.lru_cache(maxsize=1)
def _defaults() -> dict:
    from gs2e.config import load_section

    return load_section("events")


def event_settings(section: "Mapping[str, Any]") -> EventSettings:
    """The typed settings of an ``events`` section, resolved once (the CLI,
    :func:`read_settings`, tests) and passed on as the object. Keys the
    section lacks take the schema's defaults; values are not validated again
    (``gs2e.config`` did that). TypeError for settings already typed: resolve
    a section once."""
    if isinstance(section, EventSettings):
        raise TypeError("event_settings: already EventSettings (a section is resolved once)")
    base = copy.deepcopy(_defaults())
    given = copy.deepcopy(dict(section))
    sec = {**base, **given, "sampling": {**base["sampling"], **dict(given.get("sampling") or {})}}
    names = {f.name for f in fields(EventSettings)} - {"sampling", "_section"}
    kw = {k: sec[k] for k in names}
    kw["theta_range"] = tuple(float(v) for v in sec["theta_range"])
    kw["containers"] = tuple(sec["containers"] or ())
    sampling = {f.name: sec["sampling"][f.name] for f in fields(SamplingSettings)}
    sampling["substeps"] = points_per_step(sampling["mode"], sampling["substeps"])
    kw["sampling"] = SamplingSettings(**sampling)
    return EventSettings(**kw, _section=given)


def read_metadata(attrs: Mapping[str, Any], where: str) -> dict:
    """The run's metadata of an ``events.h5`` (its attributes, as
    :func:`gs2e.events.io.read_h5` gives them): the settings (``config``),
    the source's light and colour filter (``light``, ``cfa``, where set) ...;
    ``where`` names the file in errors."""
    meta = attrs.get("metadata")
    try:
        meta = json.loads(meta) if isinstance(meta, (str, bytes)) else meta
    except json.JSONDecodeError as exc:
        raise InputError(f"{where}: its metadata is not JSON ({exc!r})") from None
    if not isinstance(meta, dict):
        raise InputError(f"{where}: no metadata")
    return meta


def read_settings(attrs: Mapping[str, Any], where: str) -> EventSettings:
    """The settings an event folder was simulated with, from its ``events.h5``
    attributes (:func:`gs2e.events.io.read_h5`); ``where`` names the file in errors."""
    try:
        section = read_metadata(attrs, where)["config"]
    except (InputError, KeyError) as exc:
        raise InputError(f"{where}: no events config in its metadata ({exc!r})") from None
    return event_settings(section)
