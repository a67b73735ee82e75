"""Containers other tools open (AEDAT4, Prophesee EVT2 RAW, DAT): written by
gs2e.events.containers, read back with faery's own file reader, events and
sensor size identical; the readers' errors; the event stage writing them."""

import json
import os

import cv2
import faery
import numpy as np
import pytest

from tests.conftest import shared_data
from gs2e.cli import main
from gs2e.common.errors import InputError
from gs2e.events.containers import (CONTAINERS, ContainerWriter, read_container,
                                    write_container)
from gs2e.events.io import read_events, read_h5
from gs2e.events.models import Events

KINDS = list(CONTAINERS)
W, H = 1280, 720


def _events(t, x=None, y=None, p=None) -> Events:
    t = np.asarray(t, np.int64)
    n = len(t)
    x = np.arange(n) % W if x is None else x
    y = np.arange(n) % H if y is None else y
    p = np.arange(n) % 2 if p is None else p
    return Events(t, np.asarray(x, np.uint16), np.asarray(y, np.uint16), np.asarray(p, np.uint8))


def _random(n=200_000, seed=0) -> Events:
    """Dense events from an absolute start of 1.7e15 us over 40 s (EVT3's
    24-bit clock wraps twice), corners of a 1280x720 sensor included."""
    rng = np.random.default_rng(seed)
    t0 = 1_700_000_000_000_000
    ev = _events(np.sort(rng.integers(t0, t0 + 40_000_000, n)), rng.integers(0, W, n),
                 rng.integers(0, H, n), rng.integers(0, 2, n))
    ev.x[-1], ev.y[-1], ev.x[0], ev.y[0] = W - 1, H - 1, 0, 0
    return ev


def _faery_read(path):
    """The file through faery's public reader (no gs2e code): events, (W, H)."""
    stream = faery.events_stream_from_file(path)
    a = stream.to_array()
    return Events(a["t"].astype(np.int64), a["x"], a["y"], a["on"].astype(np.uint8)), stream.dimensions()


def _same(a: Events, b: Events) -> bool:
    return len(a) == len(b) and all(np.array_equal(getattr(a, k).astype(np.int64),
                                                   getattr(b, k).astype(np.int64)) for k in "txyp")


@pytest.mark.parametrize("kind", KINDS)
def test_round_trip_streamed(tmp_path, kind):
    ev = _random()
    path = tmp_path / f"ev{CONTAINERS[kind]}"
    with ContainerWriter(path, kind, W, H) as w:
        for i in range(0, len(ev), 30_011):  # batches that split equal-time runs too
            w.append(Events(ev.t[i:i + 30_011], ev.x[i:i + 30_011], ev.y[i:i + 30_011],
                            ev.p[i:i + 30_011]))
    assert w.n == len(ev)
    back, dims = _faery_read(path)
    assert dims == (W, H) and _same(back, ev)
    back, shape = read_events(path)
    assert shape == (H, W) and _same(back, ev)
    assert back.t.dtype == np.int64 and back.x.dtype == np.uint16 and back.p.dtype == np.uint8
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left


HARD = {
    "zero events": _events([]),
    "one event in the last pixel": _events([5], [W - 1], [H - 1], [1]),
    # quiet gaps across the 2^24 us (EVT3) and 2^26 us wraps, equal times
    "sparse wraps": _events([0, 1, (1 << 24) - 1, 1 << 24, (1 << 24) + 5, 3 * (1 << 24) + 7,
                             3 * (1 << 24) + 7, (1 << 31) + 3], [0, W - 1, 5, 6, 7, 8, 2, 9],
                            [0, H - 1, 1, 2, 3, 4, 4, 5], [1, 0, 1, 0, 1, 0, 1, 1]),
}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("case", list(HARD))
def test_round_trip_hard_cases(tmp_path, kind, case):
    ev = HARD[case]
    path = tmp_path / f"ev{CONTAINERS[kind]}"
    write_container(path, kind, ev, W, H)
    back, shape = read_events(path)
    assert shape == (H, W) and _same(back, ev)
    if not (kind == "dat" and case == "zero events"):  # faery cannot open its header-only DAT
        back, dims = _faery_read(path)
        assert dims == (W, H) and _same(back, ev)


@pytest.mark.parametrize("kind", KINDS)
def test_sensor_size_from_the_header(tmp_path, kind):
    # not faery's (1280, 720) fallback: the size comes from the header
    path = tmp_path / f"ev{CONTAINERS[kind]}"
    write_container(path, kind, _events([10, 20], [345, 0], [259, 0]), 346, 260)
    assert read_container(path)[1] == (260, 346)
    assert faery.events_stream_from_file(path).dimensions() == (346, 260)


@pytest.mark.parametrize("kind", KINDS)
def test_writer_refuses_what_the_format_cannot_hold(tmp_path, kind):
    path = tmp_path / f"ev{CONTAINERS[kind]}"
    with pytest.raises(ValueError, match="time order"):
        write_container(path, kind, _events([10, 5]), W, H)
    with pytest.raises(ValueError, match="time order"):
        with ContainerWriter(path, kind, W, H) as w:
            w.append(_events([10, 20]))
            w.append(_events([15]))
    with pytest.raises(InputError, match="negative times"):
        write_container(path, kind, _events([-3, 5]), W, H)
    with pytest.raises(InputError, match="outside the 1280x720 sensor"):
        write_container(path, kind, _events([1], [W], [0]), W, H)
    with pytest.raises(RuntimeError, match="boom"):
        with ContainerWriter(path, kind, W, H) as w:
            w.append(_events([1, 2]))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []  # nothing, not even a temporary
    with pytest.raises(ValueError, match="sensor size 0x720 is empty"):
        ContainerWriter(path, kind, 0, H)


def test_format_limits(tmp_path):
    with pytest.raises(ValueError, match="evt2 holds sensors up to 2048x2048, got 4000x3000"):
        ContainerWriter(tmp_path / "a.raw", "evt2", 4000, 3000)
    with pytest.raises(ValueError, match="unknown container 'evt3'"):
        ContainerWriter(tmp_path / "a.raw", "evt3", W, H)
    with pytest.raises(InputError, match="DAT times span at most 2"):
        write_container(tmp_path / "a.dat", "dat", _events([7, 7 + (1 << 32)]), W, H)
    # DAT holds a 4000x3000 sensor (14-bit addresses)
    write_container(tmp_path / "b.dat", "dat", _events([1], [3999], [2999]), 4000, 3000)
    back, shape = read_events(tmp_path / "b.dat")
    assert shape == (3000, 4000) and back.x[0] == 3999 and back.y[0] == 2999
    assert not (tmp_path / "a.dat").exists() and not (tmp_path / "a.raw").exists()


def test_reads_evt3_written_by_faery(tmp_path):
    # EVT3 as cameras write it (dense, clock wrapping twice): read, not written, by gs2e
    ev = _random(100_000, seed=1)
    a = np.empty(len(ev), faery.EVENTS_DTYPE)
    a["t"], a["x"], a["y"], a["on"] = ev.t, ev.x, ev.y, ev.p.astype(bool)
    path = tmp_path / "cam.raw"
    with faery.evt.Encoder(path, "evt3", True, (W, H), True) as enc:
        enc.write({"events": a})
    assert open(path, "rb").readline() == b"% evt 3.0\n"
    back, shape = read_events(path)
    assert shape == (H, W) and _same(back, ev)


@pytest.mark.parametrize("name,content,match", [
    ("bad.aedat4", b"garbage" * 10, "not a readable AEDAT4 file .*magic"),
    ("bad.raw", b"garbage" * 10, "gives no sensor size and names no camera"),
    ("noversion.raw", b"% geometry 640x480\n" + b"\x00" * 8, "not a readable Prophesee RAW .*no version"),
    ("bad.dat", b"% Width 640\n% Height 480\n" + b"\x00", "not a readable Prophesee DAT"),
])
def test_corrupt_files_are_one_line_errors(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError, match=match) as err:
        read_events(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_truncated_real_recording(tmp_path):
    raw = shared_data("events", "dvxplorer_sample.aedat4").read_bytes()
    path = tmp_path / "cut.aedat4"
    path.write_bytes(raw[: len(raw) // 2])
    with pytest.raises(InputError, match=f"{path}: not a readable AEDAT4 file"):
        read_events(path)


def test_real_recording_through_every_container(tmp_path):
    """The DVXplorer recording read with faery (count, size, time span as the
    `aedat` package read them), then written to each container and read back."""
    ev, shape = read_events(shared_data("events", "dvxplorer_sample.aedat4"))
    assert shape == (240, 320) and len(ev) == 111_954
    assert (int(ev.t[0]), int(ev.t[-1])) == (1605537493718345, 1605537494308262)
    assert int(ev.p.sum()) == 55_023 and np.all(np.diff(ev.t) >= 0)
    for kind, suffix in CONTAINERS.items():
        path = tmp_path / f"real{suffix}"
        write_container(path, kind, ev, 320, 240)
        back, back_shape = read_events(path)
        assert back_shape == (240, 320) and _same(back, ev), kind


def _pngs(folder, n=10, h=24, w=32):
    folder.mkdir()
    yy, xx = np.mgrid[0:h, 0:w]
    for i in range(n):
        img = (127 + 120 * np.sin(0.4 * (xx - 1.5 * i) + 0.2 * yy)).astype(np.uint8)
        cv2.imwrite(str(folder / f"f{i:03d}.png"), img)


def test_event_stage_writes_the_containers(tmp_path):
    _pngs(tmp_path / "imgs")
    out = tmp_path / "out"
    rc = main(["events", str(tmp_path / "imgs"), "--fps", "1000", "-o", str(out), "--set",
               "model=ideal", "--set", "containers=[aedat4, evt2, dat]", "--set", "preview=false",
               "--set", "theta_on=0.2", "--set", "theta_off=0.2"])
    assert rc == 0
    assert {p.name for p in out.iterdir()} == {"events.h5", "stats.json", "stats.parquet",
                                               "events.aedat4", "events.raw", "events.dat"}
    ref, attrs = read_h5(out / "events.h5")
    assert len(ref) > 100 and (attrs["height"], attrs["width"]) == (24, 32)
    for name in ("events.aedat4", "events.raw", "events.dat"):
        back, shape = read_events(out / name)
        assert shape == (24, 32) and _same(back, ref), name
        back, dims = _faery_read(out / name)
        assert dims == (32, 24) and _same(back, ref), name
    assert json.loads((out / "stats.json").read_text())["metadata"]["config"]["containers"] == \
        ["aedat4", "evt2", "dat"]


def test_event_stage_refuses_bad_containers_before_simulating(tmp_path, capsys):
    _pngs(tmp_path / "imgs", n=3)
    out = tmp_path / "out"
    rc = main(["events", str(tmp_path / "imgs"), "--fps", "100", "-o", str(out),
               "--set", "containers=[evt3]"])
    assert rc == 2 and "events.containers" in capsys.readouterr().err
    wide = tmp_path / "wide"
    wide.mkdir()
    for i in range(2):
        cv2.imwrite(str(wide / f"f{i}.png"), np.full((1, 2100), 100 + i, np.uint8))
    rc = main(["events", str(wide), "--fps", "100", "-o", str(out), "--set", "containers=[evt2]"])
    err = capsys.readouterr().err
    assert rc == 2 and "events.containers: evt2 holds sensors up to 2048x2048, got 2100x1" in err
    assert sorted(os.listdir(tmp_path)) == ["imgs", "wide"]  # no output, no temporary
