"""Every event reader checks every field where it enters (issue: signed
polarity written as 255, events off the declared sensor kept silently):
polarities of any convention are read as such, values that cannot be right
are one-line errors naming the file, truncated files are reported."""

from __future__ import annotations

import h5py
import numpy as np
import pytest

from gs2e.common.errors import InputError
from gs2e.events.io import read_events, read_h5
from tests.conftest import run_cli


def _dsec(path, p, x=None, y=None, attrs=None, n=None):
    n = len(p) if n is None else n
    with h5py.File(path, "w") as f:
        g = f.create_group("events")
        g["t"] = np.arange(n, dtype=np.int64) * 10
        g["x"] = np.arange(n, dtype=np.uint16) % 8 if x is None else x
        g["y"] = np.zeros(n, np.uint16) if y is None else y
        g["p"] = p
        f.attrs.update(attrs or {})
    return path


@pytest.mark.parametrize("p", [np.array([-1, 1, -1, 1], np.int8), np.array([-1.0, 1.0, -1.0, 1.0]),
                               np.array([0, 1, 0, 1], np.uint8), np.array([False, True, False, True])])
def test_any_polarity_convention_reads_as_on_off(tmp_path, p):
    ev, _ = read_h5(_dsec(tmp_path / "e.h5", p))
    assert ev.p.tolist() == [0, 1, 0, 1]


def test_signed_polarity_survives_conversion_and_stats(tmp_path):
    """v2e-style int8 -1/+1 through events-convert (HDF5 and AEDAT4) and events-stats."""
    import json

    src = _dsec(tmp_path / "v2e.h5", np.array([-1, 1, -1, -1], np.int8))
    for out in ("out.h5", "out.aedat4"):
        r = run_cli("events-convert", str(src), str(tmp_path / out), "--width", "8", "--height", "4")
        assert r.returncode == 0, r.stderr
        ev, _ = read_events(tmp_path / out)
        assert ev.p.tolist() == [0, 1, 0, 0]
    r = run_cli("events-stats", str(src), "--width", "8", "--height", "4")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stats"]["on_fraction"] == pytest.approx(0.25)


@pytest.mark.parametrize("p,msg", [(np.array([0, 2, 1, 0], np.int8), "polarity 2"),
                                   (np.array([0, -1, 1, 0], np.int8), "not one convention"),
                                   (np.array([0.0, 0.5, 1.0, 1.0]), "polarity 0.5")])
def test_impossible_polarity_is_refused(tmp_path, p, msg):
    with pytest.raises(InputError, match=msg):
        read_h5(_dsec(tmp_path / "e.h5", p))


def test_coordinates_are_checked(tmp_path):
    p = np.array([0, 1, 0, 1], np.uint8)
    with pytest.raises(InputError, match="negative x in 1 event"):
        read_h5(_dsec(tmp_path / "neg.h5", p, x=np.array([0, -3, 2, 1], np.int16)))
    with pytest.raises(InputError, match="non-integer"):
        read_h5(_dsec(tmp_path / "frac.h5", p, y=np.array([0, 1.5, 2, 1])))
    # the file's own width/height
    with pytest.raises(InputError, match="y beyond the sensor's 4 px in 2 event"):
        read_h5(_dsec(tmp_path / "off.h5", p, y=np.array([0, 4, 5, 1], np.uint16),
                      attrs={"width": 8, "height": 4}))
    # a sensor the user declares for a file that has none
    (tmp_path / "e.txt").write_text("1 12 3 1\n2 4 4 0\n")
    with pytest.raises(InputError, match="x beyond the sensor's 8 px in 1 event"):
        read_events(tmp_path / "e.txt", (8, 8))
    r = run_cli("events-convert", str(tmp_path / "e.txt"), str(tmp_path / "e.h5"), "--width", "8",
                "--height", "8")
    assert r.returncode != 0 and "x beyond the sensor's 8 px" in r.stderr.strip().splitlines()[-1]
    assert not (tmp_path / "e.h5").exists()
    ev, shape = read_events(tmp_path / "e.txt", (16, 8))
    assert shape == (8, 16) and ev.x.tolist() == [12, 4]


def test_truncated_files_are_reported(tmp_path):
    with h5py.File(tmp_path / "cut.h5", "w") as f:
        g = f.create_group("events")
        g["t"] = np.arange(5, dtype=np.int64)
        g["x"] = g["y"] = np.zeros(5, np.uint16)
        g["p"] = np.zeros(3, np.uint8)  # cut short
    with pytest.raises(InputError, match="differ in length"):
        read_h5(tmp_path / "cut.h5")
    np.savez(tmp_path / "cut.npz", t=np.arange(4), x=np.zeros(4, np.uint16), y=np.zeros(3, np.uint16),
             p=np.zeros(4, np.uint8), width=8, height=8)
    with pytest.raises(InputError, match="differ in length"):
        read_events(tmp_path / "cut.npz")
    (tmp_path / "cut2.npz").write_bytes((tmp_path / "cut.npz").read_bytes()[:100])
    with pytest.raises(InputError, match="not a gs2e event npz"):
        read_events(tmp_path / "cut2.npz")


def test_text_polarity_conventions(tmp_path):
    (tmp_path / "pm.txt").write_text("1 1 1 -1\n2 2 2 1\n")
    (tmp_path / "01.txt").write_text("1 1 1 0\n2 2 2 1\n")
    (tmp_path / "bad.txt").write_text("1 1 1 0\n2 2 2 3\n")
    assert read_events(tmp_path / "pm.txt")[0].p.tolist() == [0, 1]
    assert read_events(tmp_path / "01.txt")[0].p.tolist() == [0, 1]
    with pytest.raises(InputError, match="polarity 3"):
        read_events(tmp_path / "bad.txt")
