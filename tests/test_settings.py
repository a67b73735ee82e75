"""One declaration per setting: each typed settings object reads every key of
its part of the schema (a key without a field was dropped silently), and the
enums the schema lists are the registries' and presets' names."""

from __future__ import annotations

from dataclasses import MISSING, FrozenInstanceError, fields

import pytest

from gs2e.common.errors import ConfigError
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


class _ReadsAttrs:
    """Typed settings that record which fields were read."""

    def __init__(self, obj):
        self._obj, self.read = obj, set()

    def __getattr__(self, k):
        self.read.add(k)
        return getattr(self._obj, k)


def test_imu_settings_read_every_imu_key():
    from gs2e.export.imu import imu_settings
    from gs2e.export.settings import ExportSettings

    sec = _ReadsAttrs(ExportSettings.defaults())
    imu_settings(sec)
    assert {k for k in _keys("export") if k.startswith("imu_")} | {"metres_per_unit"} <= sec.read


def _sections() -> list[str]:
    p = load_schema()["properties"]
    return [k for k, v in p.items() if v.get("type") == "object" and "properties" in v]


# section -> its stage's typed settings (events: EventSettings, bench: BenchConfig, above)
SETTINGS = {"demo": "gs2e.demo.settings:DemoSettings", "ingest": "gs2e.io.settings:IngestSettings",
            "light": "gs2e.light.settings:LightSettings",
            "sfm": "gs2e.sfm.settings:SfmSettings", "splat": "gs2e.splat.settings:SplatSettings",
            "trajectory": "gs2e.trajectory.settings:TrajectorySettings",
            "render": "gs2e.render.settings:RenderSettings", "metrics": "gs2e.report.settings:MetricsSettings",
            "dataset": "gs2e.dataset.settings:DatasetSettings",
            "export": "gs2e.export.settings:ExportSettings"}


def test_every_section_has_typed_settings_with_a_field_per_key():
    """Every section resolves into typed settings: those of SETTINGS hold one
    field per key (no defaults of their own: the schema's fill the section),
    events and bench have the tests above."""
    from gs2e.common.registry import resolve

    assert set(SETTINGS) | {"events", "bench"} == set(_sections())
    for section, where in SETTINGS.items():
        cls = resolve(where)
        assert cls.SECTION == section
        names = [f.name for f in fields(cls)]
        assert set(names) == _keys(section), f"{section}: {set(names) ^ _keys(section)}"
        assert all(f.default is MISSING and f.default_factory is MISSING for f in fields(cls)), section
        cfg = cls.defaults()
        assert cfg.as_dict() == dict(sorted(load_section(section).items()))
        with pytest.raises(FrozenInstanceError):
            setattr(cfg, names[0], None)


def test_typed_settings_refuse_a_key_without_a_field_or_a_field_without_a_key():
    from gs2e.splat.settings import SplatSettings

    sec = load_section("splat")
    with pytest.raises(ConfigError, match="'splat.max_iteratons': not a setting of SplatSettings"):
        SplatSettings.from_section({**sec, "max_iteratons": 10})
    with pytest.raises(ConfigError, match="'splat.window' is missing"):
        SplatSettings.from_section({k: v for k, v in sec.items() if k != "window"})
    # defaults() and replace() validate and check as the CLI does
    with pytest.raises(ConfigError, match="splat.max_iteratons"):
        SplatSettings.defaults(max_iteratons=10)
    with pytest.raises(ConfigError, match="splat.max_iterations"):
        SplatSettings.defaults().replace(max_iterations=-1)
    assert SplatSettings.defaults().replace(max_iterations=7).max_iterations == 7


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


def test_a_stage_takes_its_settings_typed_not_a_dict(tmp_path):
    """A section is resolved once: the stages' functions refuse a dict with a
    TypeError naming the function, before reading or writing anything."""
    from gs2e.events.models import make_model
    from gs2e.events.settings import event_settings
    from gs2e.splat.train import train

    with pytest.raises(TypeError, match="train takes SplatSettings, not dict"):
        train(tmp_path / "no_scene", tmp_path / "out", load_section("splat"))
    with pytest.raises(TypeError, match="make_model takes EventSettings, not dict"):
        make_model(load_section("events"), (2, 3), 0)
    with pytest.raises(TypeError, match="resolved once"):
        event_settings(event_settings({}))
    assert not (tmp_path / "out").exists()

