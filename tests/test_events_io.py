"""Event I/O (DSEC HDF5, text, npz, AEDAT4), representations, stats and the CLI."""

import json
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest

from tests.conftest import shared_data
from gs2e.cli import main
from gs2e.common.errors import InputError
from gs2e.events.io import (H5EventSlicer, H5EventWriter, read_events, read_h5, read_npz, read_text,
                            write_npz, write_text)
from gs2e.events.models import Events
from gs2e.events.represent import event_frame, voxel_grid, write_preview
from gs2e.events.stats import StatsAccumulator, calibrate_noise, event_stats



def _random_events(n=50_000, W=64, H=48, t0=(1 << 33) + 17, span=2_345_678, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(t0, t0 + span, n)).astype(np.int64)
    return Events(t, rng.integers(0, W, n).astype(np.uint16), rng.integers(0, H, n).astype(np.uint16),
                  rng.integers(0, 2, n).astype(np.uint8))


def test_h5_round_trip_dsec_layout(tmp_path):
    ev = _random_events()
    t_off = int(ev.t[0]) - 5
    out = tmp_path / "ev.h5"
    with H5EventWriter(out, 64, 48, t_off, "gzip", attrs={"model": "x", "seed": 3,
                                                         "metadata": {"a": [1, 2]},
                                                         "theta/on": np.ones((48, 64), np.float32)}) as w:
        for i in range(0, len(ev), 7777):
            w.append(Events(ev.t[i:i + 7777], ev.x[i:i + 7777], ev.y[i:i + 7777], ev.p[i:i + 7777]))
    with h5py.File(out) as f:
        assert f["events/x"].dtype == np.uint16 and f["events/y"].dtype == np.uint16
        assert f["events/p"].dtype == np.uint8
        assert f["events/t"].compression == "gzip"
        t_rel = f["events/t"][()]
        assert int(f["t_offset"][()]) == t_off
        ms = f["ms_to_idx"][()]
        # DSEC semantics: ms_to_idx[i] = first index with t >= 1000 i
        want = np.searchsorted(t_rel, np.arange(len(ms)) * 1000, side="left")
        assert np.array_equal(ms, want)
        assert ms[-1] == len(t_rel) and (len(ms) - 2) * 1000 <= t_rel[-1]
        assert json.loads(f.attrs["metadata"]) == {"a": [1, 2]}
        assert "ON" in f.attrs["polarity"]
    back, attrs = read_h5(out)
    for k in "txyp":
        assert np.array_equal(getattr(back, k), getattr(ev, k))
    assert attrs["seed"] == 3 and attrs["theta/on"].shape == (48, 64)
    # window read via ms_to_idx
    a, b = int(ev.t[1000]), int(ev.t[20000])
    win, _ = read_h5(out, (a, b))
    sel = (ev.t >= a) & (ev.t < b)
    assert np.array_equal(win.t, ev.t[sel]) and np.array_equal(win.x, ev.x[sel])
    # index ranges through one handle: the same events as the time window
    i0, i1 = np.searchsorted(ev.t, [a, b])
    sl = H5EventSlicer(out)
    assert sl.n_events == len(ev)
    part = sl.read(int(i0), int(i1))
    for k in "txyp":
        got, want = getattr(part, k), getattr(win, k)
        assert np.array_equal(got, want) and got.dtype == want.dtype
    assert len(sl.read(len(ev), len(ev))) == 0
    with pytest.raises(InputError, match="ev.h5.*out of range"):
        sl.read(0, len(ev) + 1)
    sl.close()


def test_h5_writer_is_atomic(tmp_path):
    out = tmp_path / "ev.h5"
    with pytest.raises(RuntimeError):
        with H5EventWriter(out, 4, 4, 0) as w:
            w.append(_random_events(10, 4, 4, 0, 100))
            raise RuntimeError("boom")
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_text_and_npz_round_trip(tmp_path):
    ev = _random_events(2000)
    write_text(tmp_path / "e.txt", ev)
    write_text(tmp_path / "e_pm.txt", ev, polarity="pm1")
    lines = (tmp_path / "e_pm.txt").read_text().split("\n")[0].split()
    assert int(lines[3]) in (-1, 1) and int(lines[0]) == ev.t[0]
    for name in ("e.txt", "e_pm.txt"):
        back = read_text(tmp_path / name)
        for k in "txyp":
            assert np.array_equal(getattr(back, k), getattr(ev, k))
    write_npz(tmp_path / "e.npz", ev, 64, 48)
    back, shape = read_npz(tmp_path / "e.npz")
    assert shape == (48, 64) and np.array_equal(back.t, ev.t) and np.array_equal(back.p, ev.p)
    (tmp_path / "bad.txt").write_text("1 2 3\n")
    with pytest.raises(InputError, match="bad.txt"):
        read_text(tmp_path / "bad.txt")


def test_event_frame_and_voxel_grid():
    ev = _random_events(5000, 16, 12, 0, 10_000)
    fr = event_frame(ev, (12, 16))
    assert fr.shape == (2, 12, 16) and fr.sum() == 5000 and fr[1].sum() == ev.p.sum()
    s = event_frame(ev, (12, 16), mode="signed")
    assert np.array_equal(s, fr[1] - fr[0])
    half = event_frame(ev, (12, 16), 0, 5000).sum() + event_frame(ev, (12, 16), 5000, None).sum()
    assert half == 5000
    vg = voxel_grid(ev, (12, 16), 5)
    assert vg.shape == (5, 12, 16)
    assert vg.sum() == pytest.approx(2.0 * ev.p.sum() - len(ev), abs=1e-2)
    assert np.allclose(vg.sum(0), s, atol=1e-3)


def test_voxel_grid_matches_sequential_adds():
    """Same bytes as sequential float64 adds in event order (np.add.at), on a
    hard case: thousands of events on one pixel, events exactly at t0 and at
    t1 - 1, a window of one microsecond, and one bin."""
    rng = np.random.default_rng(3)
    n, H, W = 20_000, 6, 7
    t = np.sort(rng.integers(100, 900, n)).astype(np.int64)
    t[0], t[-1] = 100, 899
    x = np.where(rng.random(n) < 0.5, 3, rng.integers(0, W, n)).astype(np.uint16)
    y = np.where(x == 3, 2, rng.integers(0, H, n)).astype(np.uint16)
    ev = Events(t, x, y, rng.integers(0, 2, n).astype(np.uint8))

    def sequential(e, n_bins, t0, t1):
        grid = np.zeros(n_bins * H * W)
        tn = np.clip((e.t - float(t0)) / max(float(t1 - t0), 1.0) * (n_bins - 1), 0, n_bins - 1)
        lo = np.floor(tn).astype(np.int64)
        hi = np.minimum(lo + 1, n_bins - 1)
        pol, pix = 2.0 * e.p - 1.0, e.y.astype(np.int64) * W + e.x
        np.add.at(grid, lo * H * W + pix, pol * (1.0 - (tn - lo)))
        np.add.at(grid, hi * H * W + pix, pol * (tn - lo) * (hi != lo))
        return grid.reshape(n_bins, H, W).astype(np.float32)

    for n_bins, (t0, t1) in [(5, (100, 900)), (1, (100, 900)), (9, (450, 451)), (3, (0, 10_000))]:
        i0, i1 = np.searchsorted(t, [t0, t1])
        sub = Events(t[i0:i1], x[i0:i1], y[i0:i1], ev.p[i0:i1])
        assert voxel_grid(ev, (H, W), n_bins, t0, t1).tobytes() == sequential(sub, n_bins, t0, t1).tobytes()
    counts = np.zeros(2 * H * W, np.int32)
    np.add.at(counts, ev.p.astype(np.int64) * H * W + ev.y.astype(np.int64) * W + ev.x, 1)
    assert np.array_equal(event_frame(ev, (H, W)), counts.reshape(2, H, W))


def test_stats_and_accumulator_agree():
    ev = _random_events(30_000, 32, 24, 0, 1_000_000)
    a = StatsAccumulator((24, 32))
    for i in range(0, len(ev), 4000):
        a.update(Events(ev.t[i:i + 4000], ev.x[i:i + 4000], ev.y[i:i + 4000], ev.p[i:i + 4000]))
    r, e = a.result(), event_stats(ev, (24, 32))
    for k in ("n_events", "rate_meps", "on_fraction", "density_mean_hz", "n_iei", "iei_mean_ms"):
        assert r[k] == pytest.approx(e[k], rel=1e-9)
    for k in ("iei_median_ms", "iei_p10_ms", "iei_p90_ms"):
        assert r[k] == pytest.approx(e[k], rel=0.01)


def test_real_recording_stats_and_calibration():
    ev, shape = read_events(shared_data("events", "dvxplorer_sample.aedat4"))
    assert shape == (240, 320) and len(ev) == 111_954
    assert np.all(np.diff(ev.t) >= 0)
    s = event_stats(ev, shape)
    assert s["rate_meps"] == pytest.approx(0.19, abs=0.005)
    assert s["on_fraction"] == pytest.approx(0.49, abs=0.01)
    assert s["iei_median_ms"] == pytest.approx(26.6, abs=0.1)
    c = calibrate_noise(ev, shape)
    assert 0 < c["ba_rate_hz"] < s["density_mean_hz"]
    assert 0.3 < c["ba_on_fraction"] < 0.7


def _write_pngs(folder: Path, n=12, H=24, W=32):
    folder.mkdir()
    yy, xx = np.mgrid[0:H, 0:W]
    ts = []
    for i in range(n):
        img = (127 + 120 * np.sin(0.4 * (xx - 1.5 * i) + 0.2 * yy)).astype(np.uint8)
        cv2.imwrite(str(folder / f"f{i:03d}.png"), img)
        ts.append(1000 * i + 5)
    return ts


def test_cli_image_folder_end_to_end(tmp_path):
    ts = _write_pngs(tmp_path / "imgs")
    (tmp_path / "ts.txt").write_text("\n".join(map(str, ts)) + "\n")
    out = tmp_path / "out"
    rc = main(["events", str(tmp_path / "imgs"), "--timestamps", str(tmp_path / "ts.txt"), "-o",
               str(out), "--seed", "3", "--set", "preset=dvs346", "--set", "write_text=true",
               "--set", "write_npz=true", "--set", "preview_window_ms=2", "--set", "theta_on=0.3",
               "--set", "theta_off=0.3"])
    assert rc == 0
    assert {p.name for p in out.iterdir()} == {"events.h5", "events.txt", "events.npz",
                                               "preview.mp4", "stats.json", "stats.parquet"}
    ev, attrs = read_h5(out / "events.h5")
    assert len(ev) > 100 and attrs["t_offset"] == 5 and ev.t.min() >= 5 and ev.t.max() <= ts[-1]
    md = json.loads(attrs["metadata"])
    assert md["seed"] == 3 and md["theta_on_nominal"] == 0.3
    assert json.loads(attrs["preset"])["name"] == "dvs346"
    st = json.loads((out / "stats.json").read_text())["stats"]
    assert st["n_events"] == len(ev) and st["n_frames"] == 12
    assert np.array_equal(read_text(out / "events.txt").t, ev.t)
    cap = cv2.VideoCapture(str(out / "preview.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6  # 11 ms of events in 2 ms windows
    # outputs get the permissions of plain files, not mkstemp's 0600
    modes = {p.name: p.stat().st_mode & 0o777 for p in out.iterdir()}
    assert len(set(modes.values())) == 1, modes
    # same seed -> same bytes
    out2 = tmp_path / "out2"
    main(["events", str(tmp_path / "imgs"), "--timestamps", str(tmp_path / "ts.txt"), "-o",
          str(out2), "--seed", "3", "--set", "preset=dvs346", "--set", "preview=false",
          "--set", "theta_on=0.3", "--set", "theta_off=0.3"])
    ev2, _ = read_h5(out2 / "events.h5")
    assert np.array_equal(ev2.t, ev.t) and np.array_equal(ev2.x, ev.x) and np.array_equal(ev2.p, ev.p)


def test_cli_array_and_errors(tmp_path, capsys):
    rng = np.random.default_rng(0)
    fr = rng.uniform(0.1, 0.9, (6, 10, 12)).astype(np.float32)
    np.save(tmp_path / "a.npy", fr)
    assert main(["events", str(tmp_path / "a.npy"), "--fps", "1000", "-o", str(tmp_path / "o"),
                 "--set", "model=ideal", "--set", "theta_on=0.2", "--set", "theta_off=0.2"]) == 0
    ev_o, attrs_o = read_h5(tmp_path / "o" / "events.h5")
    assert len(ev_o) > 0 and attrs_o["model"] == "ideal"
    # the workflow passes the section as JSON
    assert main(["events", str(tmp_path / "a.npy"), "--fps", "1000", "-o", str(tmp_path / "oj"),
                 "--config-json", '{"model": "ideal", "theta_on": 0.2, "theta_off": 0.2}']) == 0
    assert np.array_equal(read_h5(tmp_path / "oj" / "events.h5")[0].t, ev_o.t)
    # non-increasing timestamps: clear error naming the file, no output
    np.savez(tmp_path / "b.npz", frames=fr, t_us=np.array([0, 10, 20, 20, 30, 40]))
    assert main(["events", str(tmp_path / "b.npz"), "-o", str(tmp_path / "o2")]) == 2
    assert "b.npz" in capsys.readouterr().err and not (tmp_path / "o2").exists()
    # NaN in a frame: error, no output
    fr[3, 2, 2] = np.nan
    np.savez(tmp_path / "c.npz", frames=fr, t_us=np.arange(6) * 100)
    assert main(["events", str(tmp_path / "c.npz"), "-o", str(tmp_path / "o3")]) == 2
    assert "NaN" in capsys.readouterr().err and not (tmp_path / "o3").exists()
    assert main(["events", str(tmp_path / "a.npy"), "-o", str(tmp_path / "o4"),
                 "--set", "model=nope", "--fps", "100"]) == 2
    assert "events.model" in capsys.readouterr().err


def test_preview_from_memory(tmp_path):
    ts = np.arange(0, 10_001, 1000)
    fr = [np.full((12, 16), 0.5, np.float32) for _ in ts]
    ev = _random_events(3000, 16, 12, 0, 10_000)
    n = write_preview(tmp_path / "p.mp4", zip(ts, fr), ev, every=2)
    assert n == 5 and (tmp_path / "p.mp4").stat().st_size > 0


def test_video_source_and_presets_command(tmp_path, capsys):
    from gs2e.events.frames import open_frame_source

    path = tmp_path / "v.avi"
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, (32, 24))
    for i in range(8):
        vw.write(np.full((24, 32, 3), 30 * i, np.uint8))
    vw.release()
    src = open_frame_source(path)
    items = list(src)
    assert len(items) == 8 and src.shape == (24, 32)
    assert [t for t, _ in items] == [20_000 * i for i in range(8)]
    assert items[0][1].dtype == np.float32 and items[-1][1].mean() > items[1][1].mean()
    assert main(["events", str(path), "-o", str(tmp_path / "o"), "--set", "model=ideal"]) == 0
    assert main(["events-presets"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {r["preset"] for r in out["voltmeter_presets"]} == {"dvs346", "dvs240", "gs2e_paper"}
    sensors = {s["name"]: s for s in out["sensors"]}
    assert (sensors["imx636"]["width"]["value"], sensors["imx636"]["height"]["value"]) == (1280, 720)
    # every value says where it comes from; nothing unpublished passes as measured
    for s in sensors.values():
        values = {**{k: v for k, v in s.items() if k != "readout"}, **s.get("readout", {})}
        for k, v in values.items():
            if isinstance(v, dict):
                assert v["source"].split(":")[0] in ("datasheet resolution (REFERENCE.md section 9)",
                                                     "assumed", "measured", "fitted"), (s["name"], k)


def test_read_ahead_keeps_order_raises_in_turn_and_stops_early():
    import threading
    import time

    from gs2e.events.frames import read_ahead

    def slow_square(i):
        time.sleep(0.002 * (i % 3))  # out-of-order completion times
        if i == 7:
            raise InputError(f"frame {i}: cannot read image")
        return i * i

    got = []
    with pytest.raises(InputError, match="frame 7"):
        for v in read_ahead(slow_square, range(20), depth=4):
            got.append(v)
    assert got == [i * i for i in range(7)]  # everything before the bad item, in order
    gen = read_ahead(slow_square, range(100), depth=3)
    assert [next(gen) for _ in range(3)] == [0, 1, 4]
    gen.close()  # the consumer stops: the reader thread ends, nothing else is started
    assert not any(t.name.startswith("gs2e-read-ahead") for t in threading.enumerate())
