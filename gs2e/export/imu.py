"""IMU of a trajectory and its calibration files (format ``imu``)::

    <out>/imu.h5                 gyro_rad_s, accel_m_s2 (Q, 3) f8: the measurements (IMU frame)
                                 gyro_true_rad_s, accel_true_m_s2: the same without noise
                                 gyro_bias_rad_s, accel_bias_m_s2: the biases added
                                 t_us (Q,) i8: sample times on the IMU's clock (trajectory
                                 time + imu_time_offset_us)
                                 p_world_m, v_world_m_s (Q, 3), q_world_imu_wxyz (Q, 4): the
                                 IMU's true pose and velocity (world frame, metres)
    <out>/imu0.csv               EuRoC's layout: timestamp [ns], w_RS_S_[xyz] [rad s^-1],
                                 a_RS_S_[xyz] [m s^-2]
    <out>/imu.yaml               Kalibr's IMU file (noise densities, random walks, rate)
    <out>/camchain.yaml          Kalibr's camera chain (pinhole, intrinsics, T_cam_imu)

Readings: :mod:`gs2e.groundtruth.imu` on the trajectory's exact derivatives
(:mod:`gs2e.trajectory.kinematics`). The trajectory is C^1: where its
acceleration jumps (the knots of its time and arc-length maps), the
accelerometer jumps too; the manifest's ``continuity`` says where and by how
much, and a warning names the largest jump when the path is not C^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gs2e.export.common import ExportOut
from gs2e.export.settings import ExportSettings
from gs2e.groundtruth.imu import (ImuNoise, add_noise, gravity_from_poses, ideal_imu, imu_noise,
                                  imu_times_us)


@dataclass(frozen=True)
class ImuSettings:
    """The ``export`` section's ``imu_*`` keys, resolved."""

    rate_hz: float
    noise: ImuNoise
    preset: str
    gravity: str | tuple[float, float, float]  # "auto" or a world vector, m/s^2
    T_cam_imu: np.ndarray
    time_offset_us: int
    metres_per_unit: float


def imu_settings(cfg: ExportSettings) -> ImuSettings:
    """The IMU's settings from the ``export`` settings (T_cam_imu and gravity
    were checked when those were built)."""
    T = np.eye(4) if cfg.imu_T_cam_imu is None else np.asarray(cfg.imu_T_cam_imu, np.float64)
    g = cfg.imu_gravity
    return ImuSettings(float(cfg.imu_rate_hz), imu_noise(cfg.imu_preset), cfg.imu_preset,
                       g if isinstance(g, str) else tuple(float(v) for v in g), T,
                       int(cfg.imu_time_offset_us), float(cfg.metres_per_unit))


@dataclass(frozen=True)
class ImuReadings:
    """One trajectory's IMU: times on the IMU clock (Q,) int64 us, measured and
    true gyroscope (rad/s) and accelerometer (m/s^2) (Q, 3), biases, the
    IMU's true pose (R_world_imu (Q, 3, 3), p_world_m, v_world_m_s (Q, 3)),
    gravity (3,) and the path's continuity report."""

    t_us: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gyro_true: np.ndarray
    accel_true: np.ndarray
    gyro_bias: np.ndarray
    accel_bias: np.ndarray
    R_world_imu: np.ndarray
    p_world_m: np.ndarray
    v_world_m_s: np.ndarray
    gravity: np.ndarray
    continuity: dict


def imu_readings(traj, st: ImuSettings, seed: int) -> ImuReadings:
    """The IMU of a trajectory at ``st.rate_hz`` over its whole span (noise
    drawn from ``seed``)."""
    from gs2e.trajectory.kinematics import acceleration_jumps, kinematics_at

    t = imu_times_us(int(traj.t_us[0]), int(traj.t_us[-1]), st.rate_hz)
    k = kinematics_at(traj, t)
    g = gravity_from_poses(traj.c2w) if st.gravity == "auto" else np.asarray(st.gravity, np.float64)
    gyro, accel = ideal_imu(k, g, st.metres_per_unit, st.T_cam_imu)
    g_m, a_m, b_g, b_a = add_noise(gyro, accel, 1.0 / st.rate_hz, st.noise, np.random.default_rng(seed))
    R_ci, r = st.T_cam_imu[:3, :3], st.T_cam_imu[:3, 3]
    R = k.c2w[:, :3, :3]
    p = k.c2w[:, :3, 3] * st.metres_per_unit + R @ r
    v = k.velocity_w * st.metres_per_unit + np.einsum("qij,qj->qi", R, np.cross(k.omega_c, r))
    return ImuReadings(t + st.time_offset_us, g_m, a_m, gyro, accel, b_g, b_a, R @ R_ci, p, v, g,
                       acceleration_jumps(traj, st.metres_per_unit))


def _yf(v: float) -> str:
    """A float as YAML 1.1 reads it back as a float (PyYAML, which Kalibr uses,
    reads Python's 4e-06 as a string: YAML 1.1 floats need a dot)."""
    import yaml

    return yaml.safe_dump(float(v)).split("\n")[0]


def kalibr_imu_yaml(st: ImuSettings, rostopic: str) -> str:
    n = st.noise
    return ("# Kalibr IMU file (github.com/ethz-asl/kalibr/wiki/yaml-formats), written by gs2e\n"
            f"# noise: {st.preset}: {n.source}\n"
            f"accelerometer_noise_density: {_yf(n.accel_noise_density)}  # m/s^2/sqrt(Hz)\n"
            f"accelerometer_random_walk: {_yf(n.accel_random_walk)}  # m/s^3/sqrt(Hz)\n"
            f"gyroscope_noise_density: {_yf(n.gyro_noise_density)}  # rad/s/sqrt(Hz)\n"
            f"gyroscope_random_walk: {_yf(n.gyro_random_walk)}  # rad/s^2/sqrt(Hz)\n"
            f"rostopic: {rostopic}\n"
            f"update_rate: {_yf(st.rate_hz)}  # Hz\n")


def opencv_intrinsics(K: np.ndarray) -> tuple[float, float, float, float]:
    """fx, fy, cx, cy with the top-left pixel's centre at (0, 0) (OpenCV, ROS,
    Kalibr) from gs2e's intrinsics (centres at +0.5, COLMAP's)."""
    return float(K[0, 0]), float(K[1, 1]), float(K[0, 2]) - 0.5, float(K[1, 2]) - 0.5


def kalibr_camchain_yaml(K: np.ndarray, width: int, height: int, st: ImuSettings, rostopic: str) -> str:
    fx, fy, cx, cy = opencv_intrinsics(K)
    rows = "\n".join(f"  - [{', '.join(_yf(v) for v in row)}]" for row in st.T_cam_imu)
    return ("# Kalibr camera chain (github.com/ethz-asl/kalibr/wiki/yaml-formats), written by gs2e\n"
            "cam0:\n"
            "  camera_model: pinhole\n"
            f"  intrinsics: [{_yf(fx)}, {_yf(fy)}, {_yf(cx)}, {_yf(cy)}]\n"
            "  distortion_model: radtan\n"
            "  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]\n"
            f"  resolution: [{int(width)}, {int(height)}]\n"
            f"  rostopic: {rostopic}\n"
            f"  timeshift_cam_imu: {_yf(st.time_offset_us * 1e-6)}\n"
            "  cam_overlaps: []\n"
            "  T_cam_imu:\n" + rows + "\n")


def write_imu(out: ExportOut, rd: ImuReadings, st: ImuSettings) -> None:
    """imu.h5 and EuRoC's imu0.csv (module docstring)."""
    import h5py

    from gs2e.common.so3 import rotmat_to_quat

    with h5py.File(out.path("imu.h5"), "w") as f:
        for name, arr in (("t_us", rd.t_us), ("gyro_rad_s", rd.gyro), ("accel_m_s2", rd.accel),
                          ("gyro_true_rad_s", rd.gyro_true), ("accel_true_m_s2", rd.accel_true),
                          ("gyro_bias_rad_s", rd.gyro_bias), ("accel_bias_m_s2", rd.accel_bias),
                          ("p_world_m", rd.p_world_m), ("v_world_m_s", rd.v_world_m_s),
                          ("q_world_imu_wxyz", rotmat_to_quat(rd.R_world_imu))):
            f.create_dataset(name, data=arr)
        f.attrs.update({"rate_hz": st.rate_hz, "preset": st.preset, "gravity_world_m_s2": rd.gravity,
                        "T_cam_imu": st.T_cam_imu, "time_offset_us": st.time_offset_us,
                        "metres_per_unit": st.metres_per_unit,
                        "conventions": "IMU frame per T_cam_imu (IMU -> camera, Kalibr); accelerometer: "
                                       "specific force (reads -g at rest); world frame: the scene's, "
                                       "scaled by metres_per_unit"})
    body = np.column_stack([rd.t_us * 1000, rd.gyro, rd.accel])
    lines = "".join(f"{int(r[0])},{r[1]!r},{r[2]!r},{r[3]!r},{r[4]!r},{r[5]!r},{r[6]!r}\n"
                    for r in body.tolist())
    out.text("imu0.csv", "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],"
                         "a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]\n" + lines)


def continuity_note(out: ExportOut, rd: ImuReadings) -> None:
    """Say where the path is not C^2 (module docstring)."""
    c = rd.continuity
    out.manifest["continuity"] = c
    if not c["c2"]:
        out.warn(f"the trajectory is C^1, not C^2: its acceleration jumps at {c['n_knots']} knots, by at "
                 f"most {c['accel_jump_max_m_s2']:.3g} m/s^2 (at t = {c['accel_jump_max_t_us']:.0f} us; RMS "
                 f"acceleration {c['accel_rms_m_s2']:.3g} m/s^2), and the accelerometer with it")


def topic_prefix(cfg: ExportSettings) -> str:
    """``export.rosbag_topic_prefix`` without a trailing slash."""
    return cfg.rosbag_topic_prefix.rstrip("/")


def write_kalibr(src, out: ExportOut, st: ImuSettings, rd: ImuReadings, prefix: str) -> None:
    """Kalibr's imu.yaml and camchain.yaml (topics under ``prefix``) and the
    continuity note: what formats imu and rosbag write alike."""
    out.text("imu.yaml", kalibr_imu_yaml(st, f"{prefix}/imu"))
    out.text("camchain.yaml", kalibr_camchain_yaml(src.K(0), src.width, src.height, st, f"{prefix}/image_raw"))
    continuity_note(out, rd)


def export_imu(src, out: ExportOut, cfg: ExportSettings, seed: int = 0) -> None:
    st = imu_settings(cfg)
    rd = imu_readings(src.trajectory, st, seed)
    write_imu(out, rd, st)
    write_kalibr(src, out, st, rd, topic_prefix(cfg))
    out.manifest.update({
        "target": "IMU (HDF5, EuRoC CSV) with Kalibr imu.yaml and camchain.yaml",
        "time": f"t_us: trajectory microseconds on the IMU's clock (offset {st.time_offset_us} us)",
        "n_samples": int(len(rd.t_us)), "rate_hz": st.rate_hz, "preset": st.preset,
        "noise": st.noise.to_dict(), "gravity_world_m_s2": rd.gravity.tolist(),
        "gravity_rule": "mean of the cameras' down (+y) axes" if st.gravity == "auto" else "given",
        "metres_per_unit": st.metres_per_unit, "seed": int(seed),
        "intrinsics": "camchain.yaml: OpenCV/Kalibr convention (top-left pixel centre at 0, 0)"})
