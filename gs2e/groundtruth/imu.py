"""An inertial measurement unit rigidly attached to the virtual camera.

Noise-free readings come from the trajectory's exact derivatives
(:func:`gs2e.trajectory.kinematics.kinematics_at`):

- gyroscope: the body angular velocity expressed in the IMU frame,
  omega_imu = R_cam_imu^T omega_cam (rad/s);
- accelerometer: the specific force in the IMU frame,
  f = R_w_imu^T (a_imu - g) (m/s^2), with a_imu the acceleration of the IMU's
  origin, a_cam + R (alpha x r + omega x (omega x r)) for its offset r from
  the camera centre, and g the gravity vector in the world frame (at rest
  an accelerometer reads -g: +9.81 m/s^2 pointing up).

Frames follow Kalibr (``T_cam_imu`` maps IMU coordinates to camera
coordinates; https://github.com/ethz-asl/kalibr/wiki/yaml-formats). Noise is
Kalibr's continuous-time model discretised at the sampling period dt
(https://github.com/ethz-asl/kalibr/wiki/IMU-Noise-Model): white noise of
standard deviation sigma / sqrt(dt) per sample, and a bias that random-walks
with standard deviation sigma_b * sqrt(dt) per sample, for each of the six
axes. The Allan deviation of such a signal falls as N / sqrt(tau) (read at
tau = 1 s) and rises as K sqrt(tau / 3) (read at tau = 3 s) (IEEE Std
952-1997, as the Kalibr wiki quotes it).

Scene units are not metres: positions are multiplied by ``metres_per_unit``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from gs2e.common.errors import ConfigError

STANDARD_GRAVITY = 9.80665  # m/s^2 (CGPM 1901)
DEG = math.pi / 180.0
MICRO_G = 1e-6 * STANDARD_GRAVITY


@dataclass(frozen=True)
class ImuNoise:
    """Kalibr's four noise parameters and where they come from.

    gyro_noise_density : rad/s/sqrt(Hz); gyro_random_walk : rad/s^2/sqrt(Hz);
    accel_noise_density : m/s^2/sqrt(Hz); accel_random_walk : m/s^3/sqrt(Hz).
    """

    gyro_noise_density: float
    gyro_random_walk: float
    accel_noise_density: float
    accel_random_walk: float
    source: str

    def to_dict(self) -> dict:
        return {"gyroscope_noise_density": self.gyro_noise_density,
                "gyroscope_random_walk": self.gyro_random_walk,
                "accelerometer_noise_density": self.accel_noise_density,
                "accelerometer_random_walk": self.accel_random_walk, "source": self.source}


# The DAVIS346 carries a TDK InvenSense MPU-6500 (iniVation, "IMU",
# docs.inivation.com/hardware/hardware-advanced-usage/imu.html). Its white-noise
# densities here are those of the MPU-6000/6050 datasheet (PS-MPU-6000A-00 rev
# 3.4: rate noise 0.005 deg/s/sqrt(Hz), accelerometer PSD 400 ug/sqrt(Hz)), the
# same InvenSense family, since the MPU-6500's own table could not be checked;
# datasheets give no bias random walk, so those are the Kalibr calibration of a
# DAVIS's MPU-6150 that rpg_ultimate_slam_open publishes
# (calibration/imu/davis_mpu6150.yaml).
IMU_PRESETS: dict[str, ImuNoise] = {
    "ideal": ImuNoise(0.0, 0.0, 0.0, 0.0, "no noise"),
    "davis346": ImuNoise(
        0.005 * DEG, 4.0e-6, 400 * MICRO_G, 0.002,
        "white noise: MPU-6000/6050 datasheet PS-MPU-6000A-00 rev 3.4 (0.005 deg/s/sqrt(Hz), "
        "400 ug/sqrt(Hz); the DAVIS346's MPU-6500 is of that family); bias random walk: "
        "rpg_ultimate_slam_open calibration/imu/davis_mpu6150.yaml"),
    "davis_ecd_kalibr": ImuNoise(
        0.05, 4.0e-6, 0.1, 0.002,
        "rpg_ultimate_slam_open calibration/imu/davis_mpu6150.yaml: the Kalibr IMU file of the "
        "Event Camera Dataset's DAVIS (inflated for estimation, as Kalibr's wiki advises)"),
}


def imu_noise(preset: str) -> ImuNoise:
    if preset not in IMU_PRESETS:
        raise ConfigError(f"export.imu_preset: '{preset}' is not one of {', '.join(IMU_PRESETS)}")
    return IMU_PRESETS[preset]


def gravity_from_poses(c2w: np.ndarray) -> np.ndarray:
    """Gravity (3,) m/s^2 in the world frame, pointing along the mean of the
    cameras' down axes (+y, OpenCV): photos are mostly taken upright, so that
    is the scene's down as far as the poses tell. Raises ConfigError when
    the cameras' down axes cancel out (set the gravity explicitly)."""
    down = np.asarray(c2w, np.float64)[:, :3, 1].mean(axis=0)
    n = float(np.linalg.norm(down))
    if n < 1e-3:
        raise ConfigError("export.imu_gravity: auto cannot tell down from the cameras' orientations "
                          "(their down axes cancel out); give the gravity vector in world coordinates")
    return STANDARD_GRAVITY * down / n


def imu_times_us(t0_us: float, t1_us: float, rate_hz: float) -> np.ndarray:
    """Sample times (int64 us) from t0 at ``rate_hz`` up to t1 (inclusive when
    it falls on the grid), rounded to whole microseconds."""
    n = int(math.floor((t1_us - t0_us) * rate_hz * 1e-6 + 1e-9)) + 1
    return np.round(t0_us + np.arange(n) * 1e6 / rate_hz).astype(np.int64)


def ideal_imu(kin, gravity_w: np.ndarray, metres_per_unit: float = 1.0,
              T_cam_imu: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Noise-free gyroscope (Q, 3) rad/s and accelerometer (Q, 3) m/s^2 in
    the IMU frame from :class:`gs2e.trajectory.kinematics.Kinematics`.

    gravity_w : (3,) m/s^2 in the world frame; T_cam_imu : (4, 4) IMU ->
    camera (Kalibr), translation in metres; None = the IMU frame is the
    camera's.
    """
    T = np.eye(4) if T_cam_imu is None else np.asarray(T_cam_imu, np.float64)
    R_ci, r_m = T[:3, :3], T[:3, 3]
    R = kin.c2w[:, :3, :3]
    w, al = kin.omega_c, kin.alpha_c
    a = kin.accel_w * metres_per_unit  # m/s^2, world
    if np.any(r_m):  # the IMU's origin moves on a lever arm around the camera centre
        r = np.broadcast_to(r_m, w.shape)
        a = a + np.einsum("qij,qj->qi", R, np.cross(al, r) + np.cross(w, np.cross(w, r)))
    f_cam = np.einsum("qji,qj->qi", R, a - np.asarray(gravity_w, np.float64))
    return w @ R_ci, f_cam @ R_ci


def add_noise(gyro: np.ndarray, accel: np.ndarray, dt_s: float, noise: ImuNoise,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Measurements = truth + bias + white noise (Kalibr's discrete model at
    period dt_s); the biases start at zero. Returns (gyro, accel, gyro_bias,
    accel_bias), each (Q, 3). The draws are made in a fixed order from
    ``rng`` (the same readings for the same seed)."""
    Q = len(gyro)
    sd = 1.0 / math.sqrt(dt_s)
    sb = math.sqrt(dt_s)
    white = rng.standard_normal((2, Q, 3))
    walk = rng.standard_normal((2, Q, 3))
    walk[:, 0] = 0.0
    b_g = np.cumsum(walk[0] * (noise.gyro_random_walk * sb), axis=0)
    b_a = np.cumsum(walk[1] * (noise.accel_random_walk * sb), axis=0)
    g = gyro + b_g + white[0] * (noise.gyro_noise_density * sd)
    a = accel + b_a + white[1] * (noise.accel_noise_density * sd)
    return g, a, b_g, b_a


def integrate_imu(t_s: np.ndarray, gyro: np.ndarray, accel: np.ndarray, R0: np.ndarray,
                  p0: np.ndarray, v0: np.ndarray, gravity_w: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dead reckoning from IMU samples (the check that the readings are the
    trajectory's): rotation by the midpoint rate over each interval, then
    velocity and position by the trapezoid rule on the world acceleration
    R f + g. t_s (Q,) seconds; gyro, accel (Q, 3) in the IMU frame; R0 (3, 3)
    IMU-to-world, p0, v0 (3,) metres and m/s. Returns R (Q, 3, 3), p (Q, 3),
    v (Q, 3)."""
    Q = len(t_s)
    R = np.empty((Q, 3, 3))
    p = np.empty((Q, 3))
    v = np.empty((Q, 3))
    R[0], p[0], v[0] = R0, p0, v0
    g = np.asarray(gravity_w, np.float64)
    a_prev = R0 @ accel[0] + g
    dts = np.diff(np.asarray(t_s, np.float64))
    dR = Rotation.from_rotvec(0.5 * (gyro[:-1] + gyro[1:]) * dts[:, None]).as_matrix()
    for k in range(Q - 1):
        dt = float(dts[k])
        R[k + 1] = R[k] @ dR[k]
        a_next = R[k + 1] @ accel[k + 1] + g
        v[k + 1] = v[k] + 0.5 * (a_prev + a_next) * dt
        p[k + 1] = p[k] + v[k] * dt + (2 * a_prev + a_next) * dt * dt / 6
        a_prev = a_next
    return R, p, v


def allan_deviation(x: np.ndarray, dt_s: float, taus_s: np.ndarray) -> np.ndarray:
    """Overlapping Allan deviation (len(taus_s), ...) of a rate signal x (Q, ...)
    sampled every dt_s, at averaging times taus_s (rounded to whole samples;
    IEEE Std 1139 / 952 estimator on the integrated signal)."""
    x = np.asarray(x, np.float64)
    theta = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0) * dt_s])
    out = []
    for tau in np.asarray(taus_s, np.float64):
        m = max(1, int(round(tau / dt_s)))
        d = theta[2 * m:] - 2 * theta[m:-m] + theta[:-2 * m]
        out.append(np.sqrt(np.mean(d * d, axis=0) / (2 * (m * dt_s) ** 2)))
    return np.array(out)


def allan_noise_fit(x: np.ndarray, dt_s: float, n_taus: int = 30) -> tuple[float, float]:
    """Kalibr's white-noise density N and random walk K of a rate signal x
    (Q,) or (Q, axes) (axes pooled), fitted to its Allan variance
    sigma^2(tau) = N^2 / tau + K^2 tau / 3 over ``n_taus`` log-spaced averaging
    times from 2 samples to a twentieth of the record, each weighted by the
    square root of its number of averages (the estimate's relative precision).
    Returns (N, K) in the signal's units per sqrt(Hz) and per sqrt(Hz) s^-1."""
    x = np.asarray(x, np.float64).reshape(len(x), -1)
    Q = len(x)
    taus = np.logspace(math.log10(2 * dt_s), math.log10(Q * dt_s / 20), n_taus)
    var = (allan_deviation(x, dt_s, taus) ** 2).mean(axis=1)
    w = np.sqrt(Q / np.round(taus / dt_s))
    c, *_ = np.linalg.lstsq(np.stack([1 / taus, taus / 3], 1) / var[:, None] * w[:, None], w, rcond=None)
    return math.sqrt(max(c[0], 0.0)), math.sqrt(max(c[1], 0.0))
