"""Sensor presets of the DVS-Voltmeter model, with explicit units.

The model (per pixel, per frame pair, L in the preset's intensity unit, t in
its time unit):

    dL = L1 - L0,  Lbar = (L0 + L1) / 2
    mu    = k1 dL / dt / (Lbar + k2) + k4 + k5 Lbar      [voltage / time unit]
    sigma = k3 sqrt(Lbar) / (Lbar + k2) + k6              [voltage / sqrt(time unit)]

Voltage is normalised so that the nominal contrast threshold is 1; gs2e scales
the ON/OFF barriers by theta_on / theta_off.

Units of k (intensity unit I, time unit T):
    k1 [-] (voltage per relative intensity change), k2 [I], k3 [I^-1/2 T^-1/2]
    (since sqrt(Lbar)/(Lbar+k2) is I^-1/2), k4 [1/T], k5 [1/(I T)], k6 [T^-1/2].

Presets:
- ``dvs346`` / ``dvs240``: the public DVS-Voltmeter code's values, in its units:
  linear intensity 0..255 (8-bit grey levels) and microseconds.
- ``gs2e_paper``: the k values quoted by the GS2E paper (0.5, 1e-3, 0.1, 0.01,
  0.1, 1e-5). They only make sense with intensity in [0, 1] and time in
  seconds: in microseconds k4 = 0.01 would mean ~10^4 leak events per pixel per
  second, and k2 = 1e-3 is 1/255 of a grey level on the 0..255 scale. With
  [0, 1] and seconds, k4 + k5 Lbar = 0.01..0.11 /s gives a leak of ~0.01-0.1
  events per pixel per second and k2 = 1e-3 is a dark floor of 0.1 % of full
  scale, both plausible for a real sensor, so we adopt those units.

Effective contrast threshold: without noise and leak, a brightness change from
L to L (1 + r) in one interval drives the voltage by k1 r L / (L + k2), so the
ON barrier theta is crossed for r = theta (1 + k2 / L) / k1; the relative
threshold is theta / k1 for bright pixels (L >> k2) and grows in the dark.
:func:`effective_threshold` reports it at a reference intensity.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from gs2e.common.errors import ConfigError


@dataclass(frozen=True)
class Preset:
    """DVS-Voltmeter parameters and the units they are expressed in."""

    name: str
    k: tuple[float, float, float, float, float, float]
    intensity_scale: float  # model intensity = linear luminance in [0, 1] * intensity_scale
    time_unit_us: float     # one model time unit in microseconds
    units: str              # human-readable units statement

    def with_k(self, overrides: dict[int, float | None] | None) -> "Preset":
        """Copy with k_i replaced where ``overrides[i]`` (i = 1..6) is not None."""
        if not overrides:
            return self
        k = list(self.k)
        for i, val in overrides.items():
            if val is not None:
                k[i - 1] = float(val)
        return replace(self, k=tuple(k))

    def to_dict(self) -> dict:
        d = asdict(self)
        d["k"] = list(self.k)
        return d


PRESETS: dict[str, Preset] = {
    "dvs346": Preset(
        "dvs346", (0.00018 * 29250, 20.0, 0.0001, 1e-7, 5e-9, 0.00001), 255.0, 1.0,
        "intensity: linear 0..255 grey levels; time: microseconds (public DVS-Voltmeter code)"),
    "dvs240": Preset(
        "dvs240", (0.000094 * 47065, 23.0, 0.0002, 1e-7, 5e-8, 0.00001), 255.0, 1.0,
        "intensity: linear 0..255 grey levels; time: microseconds (public DVS-Voltmeter code)"),
    "gs2e_paper": Preset(
        "gs2e_paper", (0.5, 1e-3, 0.1, 0.01, 0.1, 1e-5), 1.0, 1e6,
        "intensity: linear luminance in [0, 1]; time: seconds (the paper's k values)"),
}


def get_preset(name: str, k_overrides: dict[int, float | None] | None = None) -> Preset:
    """Preset by name with optional k overrides; ConfigError for unknown names."""
    try:
        p = PRESETS[name]
    except KeyError:
        raise ConfigError(f"events.preset: unknown preset '{name}' "
                          f"(choose from {', '.join(PRESETS)})") from None
    return p.with_k(k_overrides)


def effective_threshold(preset: Preset, theta: float = 1.0,
                        luminance: float | np.ndarray = 0.5) -> float | np.ndarray:
    """Relative intensity change (dL / L) that moves the voltage by ``theta``
    in one step, ignoring noise and leak, at linear luminance ``luminance`` in
    [0, 1]: theta (1 + k2 / L) / k1 with L in the preset's intensity units."""
    k1, k2 = preset.k[0], preset.k[1]
    L = np.asarray(luminance, dtype=np.float64) * preset.intensity_scale
    with np.errstate(divide="ignore"):
        r = theta * (1.0 + k2 / L) / k1
    return float(r) if np.ndim(r) == 0 else r


def effective_threshold_report(theta: float = 1.0) -> list[dict]:
    """Per preset: effective relative threshold at luminance 0.1, 0.5, 1 and
    the bright-pixel limit theta / k1, plus the equivalent log-intensity step."""
    rows = []
    for p in PRESETS.values():
        row = {"preset": p.name, "units": p.units, "theta": theta,
               "limit_theta_over_k1": theta / p.k[0],
               "log_step_limit": float(np.log1p(theta / p.k[0]))}
        for lum in (0.1, 0.5, 1.0):
            row[f"rel_threshold_at_{lum:g}"] = effective_threshold(p, theta, lum)
        rows.append(row)
    return rows
