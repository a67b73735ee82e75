"""ROS bags of a trajectory, laid out like the Event Camera Dataset's
(formats ``rosbag``: ROS 1, ``rosbag2``: ROS 2 with MCAP storage)::

    <out>/<trajectory>.bag        (rosbag)  or  <out>/<trajectory>/  (rosbag2: metadata.yaml + .mcap)
        <prefix>/events       dvs_msgs/EventArray   events of each rosbag_event_window_us window
                                                    (stamp: its last event's time; empty windows
                                                    are not written)
        <prefix>/image_raw    sensor_msgs/Image     one frame per render.fps (rosbag_image: the
                                                    blurred frame, as a frame camera records, or
                                                    the sharp one; mono8 or rgb8), stamped at its
                                                    time (the exposure's centre)
        <prefix>/camera_info  sensor_msgs/CameraInfo with every image (plumb_bob, no distortion)
        <prefix>/imu          sensor_msgs/Imu       export.imu_* (the same readings as format imu)
        <prefix>/pose         geometry_msgs/PoseStamped   the camera's true pose (camera-to-
                                                    world, OpenCV axes, metres) at
                                                    rosbag_pose_rate_hz, frame_id "world"
    <out>/imu.yaml, <out>/camchain.yaml             Kalibr's files (gs2e.export.imu)

The prefix is ``rosbag_topic_prefix`` (``/dvs``, as the Event Camera
Dataset's ``/dvs/events``, ``/dvs/image_raw``, ``/dvs/imu``,
``/dvs/camera_info``; its ground truth is ``/optitrack/davis``, a motion
capture's body pose, which a virtual camera replaces with its own). The
message types are rpg_dvs_ros's dvs_msgs (Event: uint16 x, uint16 y, time
ts, bool polarity; EventArray: Header, height, width, Event[]), which the
bag carries with its definition. Times are the trajectory's (absolute
microseconds) in nanoseconds; ROS intrinsics put the top-left pixel's centre
at (0, 0), gs2e's at (0.5, 0.5).

Written with ``rosbags`` (pure Python; the bag containers, connections and
every message but the event arrays). An event array of millions of events
as Python message objects takes seconds, so its serialized bytes are built
by numpy: ROS 1's packed 13-byte events and CDR's aligned ones, held equal
to the library's own serializer by tests.
"""

from __future__ import annotations

import heapq
from pathlib import Path
from typing import Iterator

import numpy as np

from gs2e.export.common import ExportOut
from gs2e.export.settings import ExportSettings

EVENT_MSG = "uint16 x\nuint16 y\ntime ts\nbool polarity\n"
EVENT_ARRAY_MSG = ("Header header\nuint32 height  # rows\nuint32 width  # columns\n"
                   "Event[] events\n")
EVENT_ARRAY = "dvs_msgs/msg/EventArray"


def typestore(ros: int):
    """A rosbags typestore (ROS 1 Noetic or ROS 2 Humble) with dvs_msgs."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(EVENT_MSG, "dvs_msgs/msg/Event"))
    ts.register(get_types_from_msg(EVENT_ARRAY_MSG, EVENT_ARRAY))
    return ts


def _sec_nsec(t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(t_ns, np.int64)
    return t // 1_000_000_000, t % 1_000_000_000


_ROS1_EVENT = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<u4"), ("nsec", "<u4"), ("p", "u1")])
# CDR (XCDR1, little endian): each field aligned to its size from the start of
# the payload, no trailing padding. A sequence starts 4-aligned, so its first
# Event is (x, y, sec, nsec, polarity, 1 pad) and every later one starts 2 mod 4:
# (x, y, 2 pad, sec, nsec, polarity, 1 pad); the last pad byte is not written.
_CDR_FIRST = np.dtype([("x", "<u2"), ("y", "<u2"), ("sec", "<i4"), ("nsec", "<u4"), ("p", "u1"),
                       ("pad", "u1")])
_CDR_NEXT = np.dtype([("x", "<u2"), ("y", "<u2"), ("pad0", "<u2"), ("sec", "<i4"), ("nsec", "<u4"),
                      ("p", "u1"), ("pad", "u1")])


def _fill(arr: np.ndarray, x, y, sec, nsec, p) -> bytes:
    arr["x"], arr["y"], arr["sec"], arr["nsec"], arr["p"] = x, y, sec, nsec, p
    return arr.tobytes()


def event_array_ros1(seq: int, stamp_ns: int, frame_id: str, width: int, height: int,
                     x: np.ndarray, y: np.ndarray, t_ns: np.ndarray, p: np.ndarray) -> bytes:
    """ROS 1 serialization of a dvs_msgs/EventArray (p: 1 ON, 0 OFF)."""
    s, ns = _sec_nsec([stamp_ns])
    fid = frame_id.encode()
    head = (np.array([seq, s[0], ns[0], len(fid)], "<u4").tobytes() + fid
            + np.array([height, width, len(x)], "<u4").tobytes())
    sec, nsec = _sec_nsec(t_ns)
    return head + _fill(np.empty(len(x), _ROS1_EVENT), x, y, sec, nsec, p)


def event_array_cdr(stamp_ns: int, frame_id: str, width: int, height: int, x: np.ndarray,
                    y: np.ndarray, t_ns: np.ndarray, p: np.ndarray) -> bytes:
    """ROS 2 (CDR, little endian) serialization of a dvs_msgs/EventArray."""
    s, ns = _sec_nsec([stamp_ns])
    fid = frame_id.encode() + b"\0"
    head = b"\x00\x01\x00\x00" + np.array([s[0], ns[0], len(fid)], "<u4").tobytes() + fid
    head += b"\0" * (-(len(head) - 4) % 4)  # height: 4-aligned (the 4-byte encapsulation excluded)
    head += np.array([height, width, len(x)], "<u4").tobytes()
    if len(x) == 0:
        return head
    sec, nsec = _sec_nsec(t_ns)
    first = np.zeros(1, _CDR_FIRST)
    rest = np.zeros(len(x) - 1, _CDR_NEXT)
    body = (_fill(first, x[:1], y[:1], sec[:1], nsec[:1], p[:1])
            + _fill(rest, x[1:], y[1:], sec[1:], nsec[1:], p[1:]))
    return head + body[:-1]  # no trailing padding


# ---------------------------------------------------------------- messages
def _stamp(ts, t_ns: int):
    s, ns = divmod(int(t_ns), 1_000_000_000)
    return ts.types["builtin_interfaces/msg/Time"](sec=s, nanosec=ns)


def _header(ts, ros: int, seq: int, t_ns: int, frame_id: str):
    H = ts.types["std_msgs/msg/Header"]
    if ros == 1:
        return H(seq=seq, stamp=_stamp(ts, t_ns), frame_id=frame_id)
    return H(stamp=_stamp(ts, t_ns), frame_id=frame_id)


def camera_info(ts, ros: int, seq: int, t_ns: int, K: np.ndarray, width: int, height: int):
    from gs2e.export.imu import opencv_intrinsics

    fx, fy, cx, cy = opencv_intrinsics(K)
    Kr = np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0])
    Pr = np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0])
    RoI = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                       do_rectify=False)
    mats = {"D": np.zeros(5), "K": Kr, "R": np.eye(3).ravel(), "P": Pr}
    if ros == 2:
        mats = {k.lower(): v for k, v in mats.items()}
    return ts.types["sensor_msgs/msg/CameraInfo"](
        header=_header(ts, ros, seq, t_ns, "camera"), height=height, width=width,
        distortion_model="plumb_bob", binning_x=0, binning_y=0, roi=RoI, **mats)


def image(ts, ros: int, seq: int, t_ns: int, rgb: np.ndarray, encoding: str):
    from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear

    if encoding == "mono8":  # luminance, sRGB-encoded (what the benchmark scores as grey)
        grey = linear_to_srgb(luminance(srgb_to_linear(rgb / 255.0)))
        data = np.clip(np.rint(grey * 255.0), 0, 255).astype(np.uint8)
    else:
        data = np.ascontiguousarray(rgb, np.uint8)
    h, w = data.shape[:2]
    return ts.types["sensor_msgs/msg/Image"](
        header=_header(ts, ros, seq, t_ns, "camera"), height=h, width=w, encoding=encoding,
        is_bigendian=0, step=w * (1 if encoding == "mono8" else 3), data=data.reshape(-1))


def _vec3(ts, v):
    return ts.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]), z=float(v[2]))


def _quat(ts, q):
    return ts.types["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]),
                                                    w=float(q[0]))


def imu_msg(ts, ros: int, seq: int, t_ns: int, gyro, accel, gyro_var: float, accel_var: float):
    cov = np.zeros(9)
    orientation_cov = cov.copy()
    orientation_cov[0] = -1.0  # REP 145 / sensor_msgs: no orientation estimate
    return ts.types["sensor_msgs/msg/Imu"](
        header=_header(ts, ros, seq, t_ns, "imu"), orientation=_quat(ts, (1.0, 0, 0, 0)),
        orientation_covariance=orientation_cov, angular_velocity=_vec3(ts, gyro),
        angular_velocity_covariance=np.diag([gyro_var] * 3).ravel(),
        linear_acceleration=_vec3(ts, accel),
        linear_acceleration_covariance=np.diag([accel_var] * 3).ravel())


def pose_msg(ts, ros: int, seq: int, t_ns: int, p, q_wxyz):
    P = ts.types["geometry_msgs/msg/Pose"](position=ts.types["geometry_msgs/msg/Point"](
        x=float(p[0]), y=float(p[1]), z=float(p[2])), orientation=_quat(ts, q_wxyz))
    return ts.types["geometry_msgs/msg/PoseStamped"](header=_header(ts, ros, seq, t_ns, "world"), pose=P)


# ---------------------------------------------------------------- the bag
def _bag_streams(src, cfg: ExportSettings, seed: int, ts, ros: int,
                 settings) -> tuple[dict, list[Iterator], object]:
    """Connections to open (topic -> msgtype), one time-ordered stream per
    topic of (t_ns, topic, serialized bytes), and the IMU readings."""
    from gs2e.common.so3 import rotmat_to_quat
    from gs2e.export.imu import imu_readings, topic_prefix

    ser = ts.serialize_ros1 if ros == 1 else ts.serialize_cdr
    prefix = topic_prefix(cfg)
    W, H = src.width, src.height
    t_frames = src.frames["t_us"].to_numpy().astype(np.int64)
    K = src.K(0)
    kind = {"blur": "blur", "sharp": "rgb"}[cfg.rosbag_image]
    enc = cfg.rosbag_image_encoding
    topics = {f"{prefix}/events": EVENT_ARRAY, f"{prefix}/image_raw": "sensor_msgs/msg/Image",
              f"{prefix}/camera_info": "sensor_msgs/msg/CameraInfo", f"{prefix}/imu": "sensor_msgs/msg/Imu",
              f"{prefix}/pose": "geometry_msgs/msg/PoseStamped"}

    def events():
        ev = src.events()
        w = int(cfg.rosbag_event_window_us)
        t0 = int(t_frames[0])
        k = (ev.t - t0) // w
        cuts = np.flatnonzero(np.diff(k)) + 1
        for seq, (a, b) in enumerate(zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [len(ev)]]))):
            if b <= a:
                continue
            t_ns = ev.t[a:b] * 1000
            args = (int(t_ns[-1]), "camera", W, H, ev.x[a:b], ev.y[a:b], t_ns, ev.p[a:b])
            data = event_array_ros1(seq, *args) if ros == 1 else event_array_cdr(*args)
            yield int(t_ns[-1]), f"{prefix}/events", data

    def frames():
        for i, t in enumerate(t_frames.tolist()):
            t_ns = t * 1000
            yield t_ns, f"{prefix}/image_raw", ser(image(ts, ros, i, t_ns, src.image(kind, i), enc),
                                                   "sensor_msgs/msg/Image")
            yield t_ns, f"{prefix}/camera_info", ser(camera_info(ts, ros, i, t_ns, K, W, H),
                                                     "sensor_msgs/msg/CameraInfo")

    rd = imu_readings(src.trajectory, settings, seed)
    dt = 1.0 / settings.rate_hz
    gvar = settings.noise.gyro_noise_density ** 2 / dt
    avar = settings.noise.accel_noise_density ** 2 / dt

    def imu():
        for i, t in enumerate(rd.t_us.tolist()):
            yield t * 1000, f"{prefix}/imu", ser(imu_msg(ts, ros, i, t * 1000, rd.gyro[i], rd.accel[i],
                                                          gvar, avar), "sensor_msgs/msg/Imu")

    def poses():
        from gs2e.groundtruth.imu import imu_times_us

        t = imu_times_us(int(src.trajectory.t_us[0]), int(src.trajectory.t_us[-1]),
                         float(cfg.rosbag_pose_rate_hz))
        c2w = src.trajectory.pose_at(t)
        q = rotmat_to_quat(c2w[:, :3, :3])
        p = c2w[:, :3, 3] * settings.metres_per_unit
        for i, ti in enumerate(t.tolist()):
            yield ti * 1000, f"{prefix}/pose", ser(pose_msg(ts, ros, i, ti * 1000, p[i], q[i]),
                                                   "geometry_msgs/msg/PoseStamped")

    return topics, [events(), frames(), imu(), poses()], rd


def write_bag(src, out: ExportOut, cfg: ExportSettings, seed: int, ros: int) -> dict:
    """Write the bag (ROS 1 or 2) and the Kalibr files; returns per-topic
    message counts."""
    from gs2e.export.imu import imu_settings, topic_prefix, write_kalibr

    st = imu_settings(cfg)
    ts = typestore(ros)
    topics, streams, rd = _bag_streams(src, cfg, seed, ts, ros, st)
    path = out.path(f"{src.traj}.bag" if ros == 1 else src.traj)
    if ros == 1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        comp = cfg.rosbag_compression
        if comp != "none":
            writer.set_compression(getattr(Writer.CompressionFormat, comp.upper()))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    counts = {t: 0 for t in topics}
    with writer:
        conns = {t: writer.add_connection(t, mt, typestore=ts) for t, mt in topics.items()}
        for t_ns, topic, data in heapq.merge(*streams, key=lambda m: m[0]):
            writer.write(conns[topic], t_ns, data)
            counts[topic] += 1
    write_kalibr(src, out, st, rd, topic_prefix(cfg))
    out.manifest.update({
        "target": ("ROS 1 bag" if ros == 1 else "ROS 2 bag (MCAP)") + ", Event Camera Dataset topics",
        "bag": path.name, "topics": topics, "messages": counts,
        "time": "message stamps and bag times: absolute trajectory nanoseconds",
        "events": f"dvs_msgs/EventArray per {int(cfg.rosbag_event_window_us)} us window, stamped at its "
                  "last event; polarity true = ON",
        "image": f"{cfg.rosbag_image} frames as {cfg.rosbag_image_encoding}",
        "intrinsics": "CameraInfo and camchain.yaml: top-left pixel centre at (0, 0) (ROS, OpenCV)",
        "imu_preset": st.preset, "seed": int(seed), "metres_per_unit": st.metres_per_unit})
    return counts


def export_rosbag(src, out: ExportOut, cfg: ExportSettings, seed: int = 0) -> None:
    write_bag(src, out, cfg, seed, 1)


def export_rosbag2(src, out: ExportOut, cfg: ExportSettings, seed: int = 0) -> None:
    write_bag(src, out, cfg, seed, 2)


def read_bag(path: str | Path):
    """(topic, msgtype, t_ns, message) of every message of a bag written here
    (ROS 1 file or ROS 2 folder), by the library's own reader."""
    from rosbags.highlevel import AnyReader

    p = Path(path)
    ros = 1 if p.is_file() else 2
    with AnyReader([p], default_typestore=typestore(ros)) as r:
        for c, t, raw in r.messages():
            yield c.topic, c.msgtype, t, r.deserialize(raw, c.msgtype)


__all__ = ["export_rosbag", "export_rosbag2", "read_bag", "event_array_ros1", "event_array_cdr",
           "typestore"]
