"""One declaration per setting: each typed settings object reads every key of
its part of the schema (a key without a field was dropped silently), and the
enums the schema lists are the registries' and presets' names."""

from __future__ import annotations

from dataclasses import fields

import pytest

from gs2e.config import load_schema, load_section


class _Reads(dict):
    """A section that records which keys were read."""

    def __init__(self, *a):
        super().__init__(*a)
        self.read = set()

    def __getitem__(self, k):
        self.read.add(k)
        return super().__getitem__(k)


def _keys(section: str) -> set[str]:
    return set(load_schema()["properties"][section]["properties"])


def test_event_settings_have_a_field_per_key():
    from gs2e.events.settings import EventSettings, SamplingSettings

    names = {f.name for f in fields(EventSettings)} - {"_section"}
    assert names == _keys("events")
    sampling = load_schema()["properties"]["events"]["properties"]["sampling"]["properties"]
    assert {f.name for f in fields(SamplingSettings)} == set(sampling)


@pytest.mark.parametrize("prefix,build", [
    ("recon3d_", lambda sec: __import__("gs2e.bench.recon3d", fromlist=["x"]).recon3d_settings(sec)),
    ("sim2real_", lambda sec: __import__("gs2e.bench.sim2real", fromlist=["x"]).settings_from_config(sec)),
])
def test_bench_settings_read_every_key_of_theirs(prefix, build):
    sec = _Reads(load_section("bench"))
    build(sec)
    mine = {k for k in _keys("bench") if k.startswith(prefix)}
    assert mine <= sec.read, f"keys no field reads: {mine - sec.read}"


def test_bench_config_reads_every_key_a_job_computes_with():
    from gs2e.bench.run import resolve

    sec = _Reads(load_section("bench"))
    resolve(sec)
    # the keys that name jobs (the workflow's, not a job's settings) and sim2real's own
    jobs = {"tasks", "real_video", "real_video_theta", "sim2real"}
    rest = {k for k in _keys("bench") if not k.startswith(("sim2real_", "recon3d_"))} - jobs
    assert rest <= sec.read, f"keys no field reads: {rest - sec.read}"


def test_imu_settings_read_every_imu_key():
    from gs2e.export.imu import imu_settings

    sec = _Reads(load_section("export"))
    imu_settings(sec)
    assert {k for k in _keys("export") if k.startswith("imu_")} | {"metres_per_unit"} <= sec.read


def test_enums_are_the_registries_and_presets():
    from gs2e.bench.tasks import TASKS
    from gs2e.events.models import MODELS
    from gs2e.events.presets import PRESETS
    from gs2e.events.sensors import SENSORS
    from gs2e.export.formats import FORMATS
    from gs2e.groundtruth.imu import IMU_PRESETS

    p = load_schema()["properties"]
    ev, bench, exp = p["events"]["properties"], p["bench"]["properties"], p["export"]["properties"]
    assert set(ev["preset"]["enum"]) == set(PRESETS)
    assert set(ev["model"]["enum"]) == set(MODELS)
    assert set(ev["sensor"]["enum"]) - {None, "custom"} == set(SENSORS)
    assert set(bench["sim2real_fit"]["items"]["enum"]) <= set(MODELS)
    assert bench["tasks"]["items"]["enum"] == list(TASKS)
    assert exp["formats"]["items"]["enum"] == list(FORMATS)
    assert set(exp["imu_preset"]["enum"]) == set(IMU_PRESETS)
