"""The ground-truth exports (flow, imu, rosbag, rosbag2) and the optical-flow
task, on the plane scene run through the real stages (gs2e render with
depth, gs2e events, gs2e windows): flow against its closed form, the files
read back by the readers their users have (h5py, OpenCV, PyYAML, rosbags'
own reader), every bag message against its source."""

from __future__ import annotations

import json

import h5py
import numpy as np
import pytest
import yaml

from gs2e.cli import main
from gs2e.export.run import export_trajectory
from gs2e.export.settings import ExportSettings
from gs2e.export.source import TrajectorySource

TRAJ = "pan"
FPS = 40.0


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """results/<scene> of the plane: trajectories/pan.npz, frames/pan (with depth),
    events/pan (ideal, theta 0.2), windows/pan.parquet."""
    from test_bench_consistency import _fast_pan

    from gs2e.testing import plane_model

    tmp = tmp_path_factory.mktemp("gt_plane")
    model = plane_model(tmp)
    sc = tmp / "scene"
    (sc / "trajectories").mkdir(parents=True)
    traj = sc / "trajectories" / f"{TRAJ}.npz"
    _fast_pan(tmp).rename(traj)
    render = {"fps": FPS, "exposure_us": 10_000.0, "min_coverage": 0.0}
    assert main(["render", "--model", str(model), "--trajectory", str(traj), "--out",
                 str(sc / "frames" / TRAJ), "--threads", "1", "--config-json", json.dumps(render)]) == 0
    events = {"model": "ideal", "theta_on": 0.2, "theta_off": 0.2, "preview": False}
    assert main(["events", "--model", str(model), "--trajectory", str(traj), "-o", str(sc / "events" / TRAJ),
                 "--seed", "0", "--threads", "1", "--config-json", json.dumps(events)]) == 0
    assert main(["windows", "--frames", str(sc / "frames" / TRAJ), "--events", str(sc / "events" / TRAJ),
                 "--out", str(sc / "windows" / f"{TRAJ}.parquet")]) == 0
    return sc


def _export(scene, tmp_path, fmt, seed=0, **over):
    cfg = ExportSettings.defaults(**over)
    out = tmp_path / fmt
    man = export_trajectory(scene, TRAJ, fmt, out, cfg, scene_id="plane", seed=seed)
    return out, man


def _expected_flow(src, i):
    """-f dx / Z between frames i and i+1 of the straight pan over the plane."""
    from gs2e.testing import PLANE_DEPTH

    c = src.c2w([i, i + 1])
    return -src.K(i)[0, 0] * (c[1, 0, 3] - c[0, 0, 3]) / PLANE_DEPTH


def test_flow_export(scene, tmp_path):
    import cv2

    from gs2e.groundtruth.flow import decode_dsec_png

    out, man = _export(scene, tmp_path, "flow", flow_per_event=True)
    src = TrajectorySource(scene, TRAJ)
    N = len(src.frames)
    with h5py.File(out / "flow.h5") as f:
        fw, ok = f["forward_flow_px"][:], f["forward_valid"][:].astype(bool)
        bw, okb = f["backward_flow_px"][:], f["backward_valid"][:].astype(bool)
        inst, inst_ok = f["flow_px_per_s"][:], f["flow_px_per_s_valid"][:].astype(bool)
        depth = f["depth_m"][:]
        assert f["t_us"][:].tolist() == src.frames["t_us"].tolist()
    assert fw.shape == (N - 1, src.height, src.width, 2) and inst.shape == (N, src.height, src.width, 2)
    for i in range(N - 1):
        e = _expected_flow(src, i)
        assert ok[i].mean() > 0.5
        assert np.abs(fw[i][ok[i]][:, 0] - e).max() < 1e-3
        assert np.abs(bw[i][okb[i]][:, 0] + e).max() < 1e-3
        png = cv2.imread(str(out / "forward" / f"{i:06d}.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
        f_png, v_png = decode_dsec_png(png)
        assert np.array_equal(v_png, ok[i]) and np.abs(f_png[ok[i]] - fw[i][ok[i]]).max() <= 0.5 / 128
    assert np.allclose(depth[inst_ok], 2.0, rtol=1e-5)
    # instantaneous flow: -f v_x / Z (px/s), v_x the pan's speed at the frame
    from gs2e.trajectory.kinematics import kinematics_at

    k = kinematics_at(src.trajectory, src.frames["t_us"].to_numpy())
    for i in range(N):
        assert np.allclose(inst[i][inst_ok[i]][:, 0], -src.K(i)[0, 0] * k.velocity_w[i, 0] / 2.0, rtol=1e-5)
    lines = (out / "forward_timestamps.txt").read_text().splitlines()
    assert lines[0].startswith("#") and len(lines) == N
    a, b = (int(v) for v in lines[1].split(","))
    assert (a, b) == tuple(src.frames["t_us"].iloc[:2])
    # per event: the motion field at its pixel and time
    with h5py.File(out / "event_flow.h5") as f:
        ef, ev_ok, ev_t = f["flow_px_per_s"][:], f["valid"][:].astype(bool), f["t_us"][:]
    ev = src.events()
    assert len(ef) == len(ev) and np.array_equal(ev_t, ev.t) and ev_ok.mean() > 0.9
    ke = kinematics_at(src.trajectory, ev.t[ev_ok].astype(np.float64))
    assert np.allclose(ef[ev_ok][:, 0], -src.K(0)[0, 0] * ke.velocity_w[:, 0] / 2.0, rtol=1e-4)
    assert man["n_events_with_flow"] == len(ev) and man["forward_valid_of_opaque_median"] > 0.5


def test_imu_export(scene, tmp_path):
    out, man = _export(scene, tmp_path, "imu", seed=4, imu_rate_hz=500.0,
                       imu_T_cam_imu=[[1, 0, 0, 0.01], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    with h5py.File(out / "imu.h5") as f:
        t, g = f["t_us"][:], f["gyro_rad_s"][:]
        g_true, a_true = f["gyro_true_rad_s"][:], f["accel_true_m_s2"][:]
        assert f.attrs["preset"] == "davis346"
    assert np.all(np.diff(t) == 2000)
    assert not g_true.any()  # the pan does not rotate
    # the camera's down is world +y (identity rotation): at constant speed the IMU reads up
    assert np.allclose(np.median(a_true, axis=0), [0, -9.80665, 0], atol=0.05)
    assert np.std(g[:, 0] - g_true[:, 0]) == pytest.approx(man["noise"]["gyroscope_noise_density"] * np.sqrt(500),
                                                           rel=0.3)
    csv = np.loadtxt(out / "imu0.csv", delimiter=",", skiprows=1)
    assert np.array_equal(csv[:, 0].astype(np.int64), t * 1000) and np.allclose(csv[:, 1:4], g)
    imu = yaml.safe_load((out / "imu.yaml").read_text())
    assert imu["rostopic"] == "/dvs/imu" and imu["update_rate"] == 500.0
    for k in ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
              "gyroscope_random_walk"):
        assert isinstance(imu[k], float) and imu[k] > 0
    cam = yaml.safe_load((out / "camchain.yaml").read_text())["cam0"]
    K = TrajectorySource(scene, TRAJ).K(0)
    assert cam["intrinsics"] == [K[0, 0], K[1, 1], K[0, 2] - 0.5, K[1, 2] - 0.5]
    assert cam["T_cam_imu"][0][3] == 0.01 and cam["resolution"] == [64, 48]
    assert "continuity" in man
    # the same seed gives the same readings, another seed others
    out2, _ = _export(scene, tmp_path / "again", "imu", seed=4, imu_rate_hz=500.0,
                      imu_T_cam_imu=[[1, 0, 0, 0.01], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    out3, _ = _export(scene, tmp_path / "other", "imu", seed=5, imu_rate_hz=500.0)
    with h5py.File(out2 / "imu.h5") as f2, h5py.File(out3 / "imu.h5") as f3:
        assert np.array_equal(f2["gyro_rad_s"][:], g) and not np.array_equal(f3["gyro_rad_s"][:], g)


ECD_TOPICS = {"/dvs/events": "dvs_msgs/msg/EventArray", "/dvs/image_raw": "sensor_msgs/msg/Image",
              "/dvs/camera_info": "sensor_msgs/msg/CameraInfo", "/dvs/imu": "sensor_msgs/msg/Imu",
              "/dvs/pose": "geometry_msgs/msg/PoseStamped"}


@pytest.mark.parametrize("fmt", ["rosbag", "rosbag2"])
def test_bag_reads_back_equal_to_its_source(scene, tmp_path, fmt):
    from gs2e.export.rosbag import read_bag

    out, man = _export(scene, tmp_path, fmt, seed=1, rosbag_event_window_us=5000)
    bag = out / (f"{TRAJ}.bag" if fmt == "rosbag" else TRAJ)
    src = TrajectorySource(scene, TRAJ)
    ev = src.events()
    msgs = list(read_bag(bag))
    types = {}
    for topic, mt, _, _ in msgs:
        types.setdefault(topic, mt)
    assert types == ECD_TOPICS
    stamps = [t for *_, t, _ in [(m[0], m[1], m[2], m[3]) for m in msgs]]
    assert stamps == sorted(stamps)
    got = [(t, m) for topic, _, t, m in msgs if topic == "/dvs/events"]
    k = (ev.t - int(src.frames["t_us"].iloc[0])) // 5000
    n = 0
    for t_bag, m in got:
        xs = np.array([e.x for e in m.events])
        ts = np.array([e.ts.sec * 1_000_000_000 + e.ts.nanosec for e in m.events])
        ps = np.array([e.polarity for e in m.events])
        sl = slice(n, n + len(m.events))
        assert np.array_equal(xs, ev.x[sl]) and np.array_equal(ts, ev.t[sl] * 1000)
        assert np.array_equal(ps, ev.p[sl].astype(bool))
        assert len(set(k[sl])) == 1  # one window per message
        assert t_bag == ts[-1] and m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec == ts[-1]
        assert (m.width, m.height) == (64, 48)
        n += len(m.events)
    assert n == len(ev) and man["messages"]["/dvs/events"] == len(got)
    images = [(t, m) for topic, _, t, m in msgs if topic == "/dvs/image_raw"]
    assert [t for t, _ in images] == (src.frames["t_us"].to_numpy() * 1000).tolist()
    m0 = images[0][1]
    assert m0.encoding == "mono8" and m0.data.size == 64 * 48
    info = [m for topic, _, _, m in msgs if topic == "/dvs/camera_info"][0]
    Kr = info.K if fmt == "rosbag" else info.k
    assert Kr[2] == src.K(0)[0, 2] - 0.5
    imus = [m for topic, _, _, m in msgs if topic == "/dvs/imu"]
    with h5py.File(_export(scene, tmp_path / "imu", "imu", seed=1)[0] / "imu.h5") as f:
        a = f["accel_m_s2"][:]
    assert np.array_equal([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z]
                           for m in imus], a)  # the same readings as the imu export
    poses = [m for topic, _, _, m in msgs if topic == "/dvs/pose"]
    assert len(poses) == man["messages"]["/dvs/pose"] > 1
    assert poses[-1].pose.position.x == pytest.approx(src.trajectory.c2w[-1, 0, 3])
    for f in ("imu.yaml", "camchain.yaml"):
        assert (out / f).is_file()


def test_bag_of_sharp_rgb_frames(scene, tmp_path):
    from gs2e.export.rosbag import read_bag

    out, _ = _export(scene, tmp_path, "rosbag", rosbag_image="sharp", rosbag_image_encoding="rgb8",
                     rosbag_compression="lz4", rosbag_topic_prefix="/cam0")
    src = TrajectorySource(scene, TRAJ)
    img = next(m for topic, _, _, m in read_bag(out / f"{TRAJ}.bag") if topic == "/cam0/image_raw")
    assert img.encoding == "rgb8" and np.array_equal(img.data.reshape(48, 64, 3), src.image("rgb", 0))


def test_flow_task_beats_zero_flow(scene, tmp_path):
    import pandas as pd

    out = tmp_path / "bench"
    assert main(["bench", "--task", "flow", "--frames", str(scene / "frames" / TRAJ), "--events",
                 str(scene / "events" / TRAJ), "--windows", str(scene / "windows" / f"{TRAJ}.parquet"),
                 "--out", str(out / "pan.parquet"), "--png", str(out / "pan.png")]) == 0
    df = pd.read_parquet(out / "pan.parquet")
    by = df.groupby("method")["aee_px"].mean()
    assert set(by.index) == {"zero", "contrast_max"}
    assert by["contrast_max"] < 0.5 * by["zero"], by
    assert df["psnr"].isna().all() and (out / "pan.png").is_file()


def test_schema_formats_equal_the_registry():
    from gs2e.config import load_schema
    from gs2e.export.formats import FORMATS

    enum = load_schema()["properties"]["export"]["properties"]["formats"]["items"]["enum"]
    assert enum == list(FORMATS)
    for f in FORMATS.values():
        assert callable(f.runner())


def test_unknown_format_is_one_line_before_any_output(scene, tmp_path):
    from gs2e.common.errors import ConfigError

    with pytest.raises(ConfigError, match="not one of .*rosbag2"):
        export_trajectory(scene, TRAJ, "rosbag3", tmp_path / "x", ExportSettings.defaults())
    assert not (tmp_path / "x").exists()


def test_config_checks_the_exports_inputs():
    from gs2e.common.errors import ConfigError
    from gs2e.config import check_config, load_config

    def check(over):
        check_config(load_config(over), workflow=True)

    with pytest.raises(ConfigError, match="render.write_depth"):
        check({"export": {"formats": ["flow"]}, "render": {"write_depth": False}})
    with pytest.raises(ConfigError, match="render.write_blur"):
        check({"export": {"formats": ["rosbag"]}, "render": {"write_blur": False}})
    check({"export": {"formats": ["rosbag"], "rosbag_image": "sharp"}, "render": {"write_blur": False}})
    with pytest.raises(ConfigError, match="export.trajectories: 'base_fast'"):
        check({"export": {"trajectories": ["base_fast"]}})
    with pytest.raises(ConfigError, match="imu_T_cam_imu"):
        check({"export": {"imu_T_cam_imu": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}})
    with pytest.raises(ConfigError, match="imu_gravity"):
        check({"export": {"imu_gravity": [0, 0, 0]}})
    with pytest.raises(ConfigError, match="bench.tasks: 'flow'"):
        check({"bench": {"tasks": ["flow"]}, "render": {"write_depth": False}})


@pytest.fixture(scope="module")
def silent_scene(scene, tmp_path_factory):
    """The plane scene with no events at all (thresholds no pan reaches): a
    valid, unusual input."""
    sc = tmp_path_factory.mktemp("gt_silent") / "scene"
    sc.mkdir()
    for d in ("trajectories", "frames"):
        (sc / d).symlink_to(scene / d, target_is_directory=True)
    from gs2e.testing import plane_model

    model = plane_model(sc.parent)
    events = {"model": "ideal", "theta_on": 50.0, "theta_off": 50.0, "preview": False}
    assert main(["events", "--model", str(model), "--trajectory", str(sc / "trajectories" / f"{TRAJ}.npz"),
                 "-o", str(sc / "events" / TRAJ), "--seed", "0", "--threads", "1",
                 "--config-json", json.dumps(events)]) == 0
    assert main(["windows", "--frames", str(sc / "frames" / TRAJ), "--events", str(sc / "events" / TRAJ),
                 "--out", str(sc / "windows" / f"{TRAJ}.parquet")]) == 0
    return sc


@pytest.mark.parametrize("fmt", ["flow", "rosbag", "rosbag2"])
def test_no_events_is_a_valid_export(silent_scene, tmp_path, fmt):
    from gs2e.export.rosbag import read_bag

    assert len(TrajectorySource(silent_scene, TRAJ).events()) == 0
    out, man = _export(silent_scene, tmp_path, fmt, flow_per_event=True)
    if fmt == "flow":
        with h5py.File(out / "event_flow.h5") as f:
            assert f["flow_px_per_s"].shape == (0, 2)
        assert man["n_events_with_flow"] == 0
    else:
        bag = out / (f"{TRAJ}.bag" if fmt == "rosbag" else TRAJ)
        topics = {t for t, *_ in read_bag(bag)}
        assert "/dvs/events" not in topics and "/dvs/image_raw" in topics
        assert man["messages"]["/dvs/events"] == 0


def test_one_frame_flow_export(scene, tmp_path):
    """A trajectory of one frame has no frame pairs: empty displacement flow,
    instantaneous flow for its frame, per-event flow all invalid."""
    from gs2e.export.common import ExportOut
    from gs2e.export.flow import export_flow

    src = TrajectorySource(scene, TRAJ)
    src.frames = src.frames.iloc[:1]
    out = ExportOut(tmp_path, "flow")
    export_flow(src, out, ExportSettings.defaults(flow_per_event=True))
    with h5py.File(tmp_path / "flow.h5") as f:
        assert f["forward_flow_px"].shape[0] == 0 and f["flow_px_per_s"].shape[0] == 1
        assert f["flow_px_per_s_valid"][0].mean() > 0.9
    with h5py.File(tmp_path / "event_flow.h5") as f:
        assert f["valid"].shape[0] > 0 and not f["valid"][:].any()
    assert (tmp_path / "forward_timestamps.txt").read_text().count("\n") == 1  # the header alone
