"""The frame camera: exposure and gain, and a photon-transfer model of the
pixel, ADC and response curve (``render.camera``).

The model (EMVA Standard 1288, release 4.0, "linear camera model"): a pixel of
linear value ``x`` (the trained radiance times the light's scale s(t)) over an
exposure of ``T`` seconds collects on average ``mu_e = x S T`` photo-electrons
(``S`` = ``sensitivity_e_per_s``) and ``mu_d = D T`` dark electrons, both
Poisson; the charge saturates at the full well ``F``; read noise adds
``N(0, sigma_r^2)`` electrons; the ADC gives ``DN = round(K g e)``, clipped to
[0, 2^bits - 1] after adding the black level ``b``, with
``K = (2^bits - 1 - b) / F`` DN per electron at gain 1. So a flat patch below
saturation has

    mean  mu_y    = b + K g (mu_e + mu_d)
    var   sigma_y^2 = (K g)^2 (mu_e + mu_d + sigma_r^2) + 1/12

and the photon-transfer curve (variance against mean) has slope K g and floor
(K g sigma_r)^2 + 1/12 (:func:`photon_transfer`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from gs2e.common.color import linear_to_srgb
from gs2e.common.errors import ConfigError


@dataclass(frozen=True)
class FrameCamera:
    """``render.camera``, resolved (see the schema for each key)."""

    model: str
    exposure: str
    full_well_e: float
    sensitivity_e_per_s: float
    read_noise_e: float
    dark_current_e_per_s: float
    adc_bits: int
    black_level_dn: int
    gain: float
    max_gain: float
    ae_target: float
    ae_settling_s: float
    min_exposure_us: float
    response: str

    @classmethod
    def from_section(cls, camera: dict) -> "FrameCamera":
        try:
            return cls(**camera)
        except TypeError as exc:
            raise ConfigError(f"render.camera: {exc}") from None

    @property
    def on(self) -> bool:
        return self.model == "sensor"

    @property
    def dn_max(self) -> int:
        return (1 << int(self.adc_bits)) - 1

    @property
    def dn_per_e(self) -> float:
        """K: DN per electron at gain 1 (the full well fills the range above the black level)."""
        return (self.dn_max - self.black_level_dn) / float(self.full_well_e)

    @property
    def dn_range(self) -> float:
        """DN from the black level to the top of the ADC."""
        return float(self.dn_max - self.black_level_dn)


def photon_transfer(mean_e: np.ndarray, exposure_s: float, gain: float, cam: FrameCamera
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The model's (mean DN, DN variance) of a flat patch collecting
    ``mean_e`` photo-electrons in ``exposure_s``, below saturation (EMVA 1288
    eq. for the linear camera model, with uniform quantisation noise 1/12)."""
    kg = cam.dn_per_e * gain
    e = np.asarray(mean_e, np.float64) + cam.dark_current_e_per_s * exposure_s
    return cam.black_level_dn + kg * e, kg * kg * (e + cam.read_noise_e ** 2) + 1.0 / 12.0


def capture(x_lin: np.ndarray, exposure_us: float, gain: float, cam: FrameCamera,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """One exposure through the camera.

    Parameters
    ----------
    x_lin : (H, W, 3) linear values (trained radiance x light scale, >= 0;
        the exposure's mean for a blurred frame).
    exposure_us, gain : the frame's exposure (us) and analogue gain.
    rng : the frame's own generator (seeded per frame: threads cannot change it).

    Returns
    -------
    (DN (H, W, 3) uint16 in [0, 2^bits - 1], saturated (H, W, 3) bool: the
    full well or the ADC's top reached).
    """
    t_s = float(exposure_us) * 1e-6
    lam = np.maximum(np.asarray(x_lin, np.float64), 0.0) * cam.sensitivity_e_per_s * t_s \
        + cam.dark_current_e_per_s * t_s
    e = rng.poisson(lam).astype(np.float64)
    full = e >= cam.full_well_e
    e = np.minimum(e, cam.full_well_e)
    if cam.read_noise_e > 0:
        e = e + rng.normal(0.0, cam.read_noise_e, size=e.shape)
    dn = np.rint(e * cam.dn_per_e * gain + cam.black_level_dn)
    top = dn >= cam.dn_max
    return np.clip(dn, 0, cam.dn_max).astype(np.uint16), full | top


def clean_dn(x_lin: np.ndarray, exposure_us: float, gain: float, cam: FrameCamera) -> np.ndarray:
    """The noiseless DN above the black level (float64, clipped to full
    scale) of ``x_lin``: the ground truth a sharp frame stands for at the
    same exposure and gain."""
    t_s = float(exposure_us) * 1e-6
    e = np.minimum(np.maximum(np.asarray(x_lin, np.float64), 0.0) * cam.sensitivity_e_per_s * t_s,
                   cam.full_well_e)
    return np.minimum(e * cam.dn_per_e * gain, cam.dn_range)


def encode(dn: np.ndarray, cam: FrameCamera, black: bool = True) -> np.ndarray:
    """DN through the response curve: (..., 3) float64 in [0, 1] to write
    (``black``: ``dn`` holds the black level, which is taken off first)."""
    y = (np.asarray(dn, np.float64) - (cam.black_level_dn if black else 0.0)) / cam.dn_range
    return linear_to_srgb(y) if cam.response == "srgb" else np.clip(y, 0.0, 1.0)


class AutoExposure:
    """Exposure and gain per frame: fixed, or an auto-exposure loop.

    The loop meters the mean linear signal ``m`` (fraction of full scale) of
    the frame just taken and moves the log of the total exposure ``T g`` by
    ``a = 1 - exp(-dt / ae_settling_s)`` of the way to ``T g ae_target / m``
    (a first-order loop with that time constant); the exposure takes what it
    can up to ``max_exposure_us`` (the frame interval), the gain the rest up
    to ``max_gain``. :meth:`prime` starts it settled on the first frame.
    """

    def __init__(self, cam: FrameCamera, exposure_us: float, max_exposure_us: float):
        self.cam = cam
        self.max_exposure_us = float(max_exposure_us)
        self.exposure_us = float(exposure_us)
        self.gain = float(cam.gain)
        self.auto = cam.exposure == "auto"

    def _set_total(self, total: float) -> None:
        cam = self.cam
        total = min(max(total, cam.min_exposure_us), self.max_exposure_us * cam.max_gain)
        self.exposure_us = min(total, self.max_exposure_us)
        self.gain = min(max(total / self.exposure_us, 1.0), cam.max_gain)

    def signal(self, x_lin: np.ndarray) -> float:
        """Mean linear signal (fraction of full scale, clipped per pixel) of
        ``x_lin`` at the current exposure and gain, noiseless."""
        return float(np.mean(clean_dn(x_lin, self.exposure_us, self.gain, self.cam))) / self.cam.dn_range

    def prime(self, x_lin: np.ndarray) -> None:
        """Settle on the first frame (a camera that has been running)."""
        if not self.auto:
            return
        for _ in range(8):  # clipping makes one step short of the target; a few converge
            m = self.signal(x_lin)
            if m <= 0:
                self._set_total(self.max_exposure_us * self.cam.max_gain)
                return
            self._set_total(self.exposure_us * self.gain * self.cam.ae_target / m)

    def update(self, mean_signal: float, dt_s: float) -> None:
        """After a frame of metered ``mean_signal``, ``dt_s`` before the next."""
        if not self.auto:
            return
        a = 1.0 - math.exp(-max(dt_s, 0.0) / self.cam.ae_settling_s)
        total = self.exposure_us * self.gain
        goal = (total * self.cam.ae_target / mean_signal if mean_signal > 0
                else self.max_exposure_us * self.cam.max_gain)
        self._set_total(math.exp(math.log(total) + a * (math.log(goal) - math.log(total))))
