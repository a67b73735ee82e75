"""Target sensors: the camera an event stream is simulated for.

A sensor preset (``events.sensor``) sets the virtual event camera -- its pixel
array and a field of view fitted to the scene's camera -- and the pixel
non-idealities the event models have: per-pixel threshold mismatch, refractory
period and background activity (leak and shot noise). Every value carries its
source; a value nobody has published or measured for that sensor is labelled
``assumed`` and says where the number comes from.

The contrast threshold itself stays the event model's (``events.preset``,
``events.theta_on`` / ``theta_off``): the only published calibration of the
DVS-Voltmeter model is the DAVIS346 one (k1..k6 of its public code), and the
Prophesee datasheet figures are not public. A sensor whose thresholds were
fitted to a real recording says so in ``extra["model"]`` (davis240: the
model and thresholds to set; ``gs2e events-presets`` lists them), and
``gs2e bench-sim2real`` applies them; the event stage does not, so a config
keeps one meaning for ``theta_on``. Hot pixels, the photoreceptor's
bandwidth and the readout (:mod:`gs2e.events.readout`) sit in
``extra["readout"]`` where a preset has measured them; none has measured a
bandwidth or a readout.

Field of view (``events.sensor_fit``): the sensor camera is the trajectory's
camera scaled uniformly about the image centre so that

* ``cover``: the sensor image is filled (aspect mismatch crops the scene
  camera's view; the default, no empty borders), or
* ``contain``: the whole scene-camera view is inside the sensor image
  (aspect mismatch leaves borders that see past the views' framing).

The geometry is :mod:`gs2e.common.camera`'s; the render stage renders the
dataset frames through the same fitted camera, so frames and events share
one camera.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gs2e.common.camera import fit_scale, size_problem
from gs2e.common.errors import ConfigError, InputError
from gs2e.common.registry import PluginRegistry, add
from gs2e.common.settings import require
from gs2e.events.settings import EventSettings

# The pixel non-idealities a sensor sets, and their value without a sensor.
NOISE_KEYS = {"theta_mismatch_sigma": 0.0, "refractory_us": 0.0, "leak_rate_hz": 0.0,
              "leak_light_rate_hz": 0.0,
              "shot_noise_rate_hz": 0.0, "shot_noise_on_fraction": 0.5}

# the sensor around the pixel (gs2e.events.readout) and the value without config or sensor
READOUT_KEYS = {"photoreceptor_cutoff_hz": None, "photoreceptor_dark_fraction": 0.1,
                "hot_pixel_fraction": 0.0, "hot_pixel_rate_hz": 0.0, "hot_pixel_on_fraction": 0.5,
                "readout_rate_meps": None, "readout_latency_us": 0.0, "readout_jitter_us": 0.0,
                "readout_queue_events": 1024}

_V2E = "assumed: v2e's default (REFERENCE.md section 9); not published for this sensor"
_MISMATCH = ("assumed: 15 % of the threshold, as DVS128's 2.1 % contrast mismatch at a ~15 % "
             "threshold (Lichtsteiner et al., JSSC 2008) and v2e's 0.03 around 0.2")
_REFRACTORY = "assumed: ESIM's and IEBCS's default 100 us (REFERENCE.md section 9)"


@dataclass(frozen=True)
class Sourced:
    """A preset value and where it comes from."""

    value: float | int | None
    source: str


@dataclass(frozen=True)
class Sensor:
    """An event camera: pixel array and pixel non-idealities, each sourced.

    ``theta_mismatch_rel`` is the per-pixel threshold std as a fraction of the
    nominal threshold (so it holds for any model's threshold units); rates in
    events per pixel per second; ``refractory_us`` in microseconds.
    """

    name: str
    description: str
    width: Sourced
    height: Sourced
    theta_mismatch_rel: Sourced
    refractory_us: Sourced
    leak_rate_hz: Sourced
    shot_noise_rate_hz: Sourced
    shot_noise_on_fraction: Sourced
    extra: dict = field(default_factory=dict)
    leak_light_rate_hz: Sourced = Sourced(0.0, "assumed: a leak rate independent of the light")

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return int(self.width.value), int(self.height.value)

    def to_dict(self) -> dict:
        out = {"name": self.name, "description": self.description}
        for k in ("width", "height", "theta_mismatch_rel", "refractory_us", "leak_rate_hz",
                  "leak_light_rate_hz",
                  "shot_noise_rate_hz", "shot_noise_on_fraction"):
            v = getattr(self, k)
            out[k] = {"value": v.value, "source": v.source}
        for k, v in self.extra.items():
            if k == "readout":
                out[k] = {key: {"value": sv.value, "source": sv.source} for key, sv in v.items()}
            else:
                out[k] = v
        return out


def _sensor(name, description, w, h, size_source, ba=None, ba_on=None, refractory=None,
            **extra) -> Sensor:
    return Sensor(
        name, description, Sourced(w, size_source), Sourced(h, size_source),
        Sourced(0.15, _MISMATCH), refractory or Sourced(100.0, _REFRACTORY),
        Sourced(0.01, _V2E + " (leak 0.01 Hz)"),
        ba or Sourced(0.001, _V2E + " (shot noise 0.001 Hz)"),
        ba_on or Sourced(0.5, "assumed: balanced ON/OFF background activity"), dict(extra))


_RES = "datasheet resolution (REFERENCE.md section 9)"
_DVX = "the DVXplorer recording ../shared/data/events/dvxplorer_sample.aedat4 (320x240 readout)"
_STREET = ("the still region of the DAVIS346 recording ../shared/data/events/davis346_street_aps.aedat4 "
           "(APS std < 0.01 over 2.36 s, 2 px from any moving pixel: 83 % of the pixels, mean APS "
           "0.303; gs2e events-stats --aps, gs2e.events.stats.still_background)")
_LEAK_FIT = (f"a line in brightness through the 5 brightness bins of {_STREET} less their shot noise "
             "(gs2e.events.stats.leak_against_brightness; parasitic photocurrent, Nozaki and Delbruck, "
             "IEEE TED 2017)")
_SLIDER = ("fitted: to the real events of ECD slider_depth (DAVIS240C; ../shared/data/slider_depth) "
           "along its recorded path by gs2e bench-sim2real (make sim2real; gs2e.bench.sim2real.fit_model)")
_BUILT_IN: dict[str, Sensor] = {
    "davis346": Sensor(
        "davis346", "iniVation DAVIS346 (DVS + APS)", Sourced(346, _RES), Sourced(260, _RES),
        Sourced(0.15, _MISMATCH), Sourced(100.0, _REFRACTORY),
        Sourced(0.001115, f"measured: the leak at zero brightness, {_LEAK_FIT}; 0.002213 (the leak "
                          "at the mean brightness, constant) before, 0.01 Hz (v2e's default) before that"),
        Sourced(0.0003185, f"measured: twice the OFF background rate at the mean brightness, in "
                           f"{_STREET}; 0.001 Hz (v2e's default) before"),
        Sourced(0.5, "assumed: balanced shot noise (the background's excess ON events are leak)"),
        {"readout": {"hot_pixel_fraction": Sourced(0.0, f"measured: no still pixel fires over 10x the "
                                                        f"background rate in {_STREET} (the most "
                                                        "active one: 4 events in 2.36 s)")}},
        Sourced(0.003619, f"measured: the leak's growth per unit of APS brightness, {_LEAK_FIT}")),
    "color_davis346": Sensor(
        "color_davis346", "iniVation Color-DAVIS346 (DVS + APS under an RGBG Bayer filter)",
        Sourced(346, _RES), Sourced(260, _RES),
        Sourced(0.15, _MISMATCH), Sourced(100.0, _REFRACTORY),
        Sourced(0.001115, "assumed: as davis346 (the same pixel; measured there)"),
        Sourced(0.0003185, "assumed: as davis346 (the same pixel; measured there)"),
        Sourced(0.5, "assumed: balanced shot noise, as davis346"),
        {"cfa": {"value": "RGGB", "source": (
            "assumed: the 2x2 phase of Color-DAVIS346's RGBG Bayer filter (Scheerlinck et al., 'CED: "
            "Color Event Camera Dataset', CVPRW 2019) as EventNeRF's colour loader reads it: R at even "
            "rows and even columns, B at odd rows and odd columns (nerf_sample_ray_split.py)")},
         "readout": {"hot_pixel_fraction": Sourced(0.0, "assumed: as davis346")}},
        Sourced(0.003619, "assumed: as davis346 (the same pixel; measured there)")),
    "davis240": Sensor(
        "davis240", "iniVation DAVIS240C (DVS + APS)", Sourced(240, _RES), Sourced(180, _RES),
        Sourced(0.05, _SLIDER), Sourced(300.0, _SLIDER),
        Sourced(0.01, _V2E + " (leak 0.01 Hz; the recording has no still region)"),
        Sourced(0.001, _V2E + " (shot noise 0.001 Hz)"),
        Sourced(0.5, "assumed: balanced ON/OFF background activity"),
        {"model": {"value": "voltmeter", "preset": "dvs346", "theta_on": 1.791, "theta_off": 1.596,
                   "source": f"{_SLIDER}: DVS-Voltmeter with its DAVIS346 preset (k1..k6), the "
                             "closer of the ideal and voltmeter fits (sum of the distances)"}}),
    "dvxplorer": _sensor(
        "dvxplorer", "iniVation DVXplorer", 640, 480, _RES,
        ba=Sourced(0.557, f"measured: background-activity rate of {_DVX} (95 % 0.531-0.581 Hz; "
                          "scene-dependent; gs2e events-stats)"),
        ba_on=Sourced(0.542, f"measured: ON fraction of the background events of {_DVX} "
                             "(95 % 0.536-0.548)"),
        refractory=Sourced(197.0, f"measured: smallest per-pixel inter-event interval of {_DVX} "
                                  "(the sensor's readout period; an upper bound of the refractory "
                                  "period)")),
    "prophesee_gen3": _sensor("prophesee_gen3", "Prophesee Gen3 VGA (CD)", 640, 480, _RES),
    "imx636": _sensor("imx636", "Sony IMX636 / Prophesee Gen4 HD", 1280, 720, _RES),
}


def register_sensor(sensor: Sensor) -> Sensor:
    """Add a sensor preset to :data:`SENSORS` under its name (a plug-in's
    entry point of ``gs2e.sensors``; see :mod:`gs2e.common.registry`)."""
    return add(SENSORS, sensor.name, sensor, "sensor preset")


SENSORS = PluginRegistry("gs2e.sensors")  # the built-in presets, then any plug-in's
for _s in _BUILT_IN.values():
    register_sensor(_s)
SENSORS.plugins(register_sensor, lambda s: s.name)


def load_sensor_file(path: str | Path) -> Sensor:
    """:func:`read_sensor_file`, read once per file version (a stage asks for
    its sensor many times; the file's modification time and size key it)."""
    p = Path(path)
    try:
        st = p.stat()
    except OSError:
        return read_sensor_file(p)  # its one-line error
    return _sensor_file_cached(str(p.resolve()), st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=16)
def _sensor_file_cached(path: str, mtime_ns: int, size: int) -> Sensor:
    return read_sensor_file(path)


def read_sensor_file(path: str | Path) -> Sensor:
    """A ``custom`` sensor from YAML: ``width`` and ``height`` (required) and
    any of ``theta_mismatch_rel``, ``refractory_us``, ``leak_rate_hz``, ``leak_light_rate_hz``,
    ``shot_noise_rate_hz``, ``shot_noise_on_fraction``; each a number or
    ``{value: ..., source: ...}``. Missing values are 0 (0.5 for the ON
    fraction), labelled as such. ``gs2e events-stats --write-preset`` writes
    this layout."""
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: cannot read the sensor file ({exc})") from exc
    if not isinstance(doc, dict):
        raise InputError(f"{path}: a sensor file is a YAML mapping")

    def val(key, default=None):
        v = doc.get(key)
        if v is None:
            if default is None:
                raise InputError(f"{path}: sensor file lacks '{key}'")
            return Sourced(default, f"not in {path.name}: gs2e's default")
        if isinstance(v, dict):
            if "value" not in v:
                raise InputError(f"{path}: '{key}' needs a 'value'")
            src, v = str(v.get("source", f"custom sensor file {path.name}")), v["value"]
        else:
            src = f"custom sensor file {path.name}"
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise InputError(f"{path}: '{key}' must be a number, got {v!r}") from None
        if not np.isfinite(v) or v < 0:
            raise InputError(f"{path}: '{key}' must be finite and >= 0, got {v}")
        return Sourced(v, src)

    w, h = val("width"), val("height")
    for s in (w, h):
        if s.value < 1 or s.value != int(s.value):
            raise InputError(f"{path}: width and height must be positive integers")
    why = size_problem(int(w.value), int(h.value))
    if why:
        raise InputError(f"{path}: sensor {why}")
    on = val("shot_noise_on_fraction", 0.5)
    if on.value > 1:
        raise InputError(f"{path}: 'shot_noise_on_fraction' must be in [0, 1]")
    readout = {k: val(k) for k in READOUT_KEYS if doc.get(k) is not None}
    for k in ("hot_pixel_fraction", "hot_pixel_on_fraction"):
        if k in readout and readout[k].value > 1:
            raise InputError(f"{path}: '{k}' must be in [0, 1]")
    return Sensor(str(doc.get("name", path.stem)), str(doc.get("description", f"custom ({path.name})")),
                  Sourced(int(w.value), w.source), Sourced(int(h.value), h.source),
                  val("theta_mismatch_rel", 0.0), val("refractory_us", 0.0),
                  val("leak_rate_hz", 0.0), val("shot_noise_rate_hz", 0.0), on,
                  {"readout": readout} if readout else {}, val("leak_light_rate_hz", 0.0))


def get_sensor(settings: "EventSettings") -> Sensor | None:
    """The sensor the ``events`` settings (or section) ask for (None: no sensor)."""
    cfg = require(settings, EventSettings, "get_sensor")
    name = cfg.sensor
    if name is None:
        return None
    if name == "custom":
        if not cfg.sensor_file:
            raise ConfigError("events.sensor=custom needs events.sensor_file (a sensor YAML)")
        return load_sensor_file(cfg.sensor_file)
    try:
        return SENSORS[name]
    except KeyError:
        raise ConfigError(f"events.sensor: unknown sensor '{name}' "
                          f"(choose from {', '.join([*SENSORS, 'custom'])})") from None


def resolve_noise(settings: "EventSettings", theta_nominal: float) -> tuple[dict, dict]:
    """The pixel non-idealities the models get: an explicit config value wins,
    then the sensor's, then none (0; ON fraction 0.5).

    Returns (values, sources): ``values`` maps each key of :data:`NOISE_KEYS`
    to a float (``theta_mismatch_sigma`` in the model's threshold units: the
    config's, else the config's ``theta_mismatch_rel`` or the sensor's
    relative mismatch x ``theta_nominal``); ``sources`` says where each came from.
    """
    cfg = require(settings, EventSettings, "resolve_noise")
    sensor = get_sensor(cfg)
    values, sources = {}, {}
    for key, default in NOISE_KEYS.items():
        if key == "theta_mismatch_sigma" and cfg.theta_mismatch_rel is not None:
            if cfg.theta_mismatch_sigma is not None:
                raise ConfigError("events.theta_mismatch_sigma and events.theta_mismatch_rel are both set "
                                  "(set one)")
            values[key] = float(cfg.theta_mismatch_rel) * float(theta_nominal)
            sources[key] = "config (theta_mismatch_rel)"
        elif getattr(cfg, key) is not None:
            values[key], sources[key] = float(getattr(cfg, key)), "config"
        elif sensor is not None:
            if key == "theta_mismatch_sigma":
                s = sensor.theta_mismatch_rel
                values[key] = float(s.value) * float(theta_nominal)
            else:
                s = getattr(sensor, key)
                values[key] = float(s.value)
            sources[key] = f"sensor {sensor.name}: {s.source}"
        else:
            values[key], sources[key] = default, "default (no sensor)"
    return values, sources


def fit_frame(frame: np.ndarray, sensor_w: int, sensor_h: int, fit: str = "cover") -> np.ndarray:
    """A (H, W) frame as the sensor sees it: scaled uniformly about the centre
    (area filter when shrinking), cropped (cover) or padded with zeros
    (contain) to (sensor_h, sensor_w); the same geometry as :func:`fit_camera`."""
    import cv2

    H, W = frame.shape
    s = fit_scale(W, H, sensor_w, sensor_h, fit)
    # output pixel centre u + 0.5 samples input x = (u + 0.5 - ox) / s - 0.5 (pixel-centre grid)
    ox, oy = (sensor_w - s * W) / 2, (sensor_h - s * H) / 2
    M = np.array([[s, 0.0, ox + 0.5 * s - 0.5], [0.0, s, oy + 0.5 * s - 0.5]])
    src = np.ascontiguousarray(frame, dtype=np.float32)
    if s < 1:  # integrate over the footprint first: plain warping would alias
        k = int(np.floor(1 / s))
        if k > 1:
            src = cv2.resize(src, (max(1, W // k), max(1, H // k)), interpolation=cv2.INTER_AREA)
            fx, fy = W / src.shape[1], H / src.shape[0]
            M = M @ np.array([[fx, 0.0, 0.5 * fx - 0.5], [0.0, fy, 0.5 * fy - 0.5], [0, 0, 1.0]])
    # edge pixels replicate (a centre within half a pixel of the image edge is still
    # inside the view); what lies outside the view (contain's borders) is black
    out = cv2.warpAffine(src, M, (sensor_w, sensor_h), flags=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
    if fit == "contain":
        u = (np.arange(sensor_w) + 0.5 - ox) / s
        v = (np.arange(sensor_h) + 0.5 - oy) / s
        out[(v < 0) | (v > H)] = 0.0
        out[:, (u < 0) | (u > W)] = 0.0
    return out


def resolve_cfa(settings: "EventSettings") -> str | None:
    """The colour filter over the event pixels: ``events.cfa`` when set
    (``none``: no filter), else the sensor's (``Sensor.extra['cfa']``), else
    None: every pixel sees the luminance."""
    cfg = require(settings, EventSettings, "resolve_cfa")
    if cfg.cfa is not None:
        return None if cfg.cfa == "none" else cfg.cfa
    sensor = get_sensor(cfg)
    cfa = (sensor.extra.get("cfa") or {}) if sensor is not None else {}
    return cfa.get("value")


def sensor_table() -> list[dict]:
    """Every built-in sensor with each value's source (``gs2e events-presets``)."""
    return [s.to_dict() for s in SENSORS.values()]
