"""Ground truth no real sensor gives, from the rendered depth and the
continuous trajectory: optical flow (:mod:`gs2e.groundtruth.flow`) and an
IMU (:mod:`gs2e.groundtruth.imu`).

Pure functions on arrays; the exports (:mod:`gs2e.export.flow`,
:mod:`gs2e.export.imu`, :mod:`gs2e.export.rosbag`) write them and the
benchmark's optical-flow task (:mod:`gs2e.bench.flow_task`) scores against
them.
"""
