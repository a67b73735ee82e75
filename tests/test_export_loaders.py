"""The few loader lines each export depends on, re-implemented from the
methods' public code (each helper cites the repository, file and lines it
follows), and fast checks of gs2e's loader-time placement against them.
tests/test_export_formats.py runs the same helpers on real exports.

Sources (snapshots read with the search tools):
r00tman/EventNeRF 44297dd, deguchihiroyuki/E2GS 68e5614, iCVTEAM/E2NeRF 487fec1,
uzh-rpg/EvDeblurNeRF 4111020, WU-CVGL/IncEventGS 28d070f, lanpokn/Event-3DGS d6d12b8.
"""

from __future__ import annotations

import numpy as np
import pytest

from gs2e.common.errors import ConfigError
from gs2e.events.models import Events
from gs2e.export.common import times_in_loader_windows
from gs2e.export.eventnerf import choose_winsize, loader_bounds_s, loader_events
from gs2e.export.inceventgs import pose_times_s
from gs2e.export.windows import compute_windows


# ---------------------------------------------------------------- EventNeRF
def eventnerf_config(text: str) -> dict[str, str]:
    """key = value lines of a configargparse file (comments skipped)."""
    out = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if "=" in line:
            k, v = (s.strip() for s in line.split("=", 1))
            out[k] = v
    return out


def eventnerf_samplers(ts: np.ndarray, n_files: int, skip: int, max_winsize: int, winsize: int,
                       cycle: bool = False) -> list[tuple[int, int, int]]:
    """(view i, start, end) of every ray sampler load_event_data_split builds,
    with the window length fixed to ``winsize``; events[start:end] are its events.

    EventNeRF data_loader_split.py L45-47 (files[::skip]), L86-87 (first view
    0 if cycled else 1 + max_winsize), L101-107 and L124 (window
    [(i - winsize) / (N - 1), i / (N - 1)) x t.max(), np.searchsorted left)."""
    n = len(range(0, n_files, skip))
    out = []
    for i in range(0 if cycle else 1 + max_winsize, n):
        start_time = (i - winsize) / (n - 1)
        if start_time < 0:
            start_time += 1
        end = np.searchsorted(ts, (i / (n - 1)) * ts.max())
        out.append((i, int(np.searchsorted(ts, start_time * ts.max())), int(end)))
    return out


# ddp_train_nerf.py L762 (testskip default 8), L768 (winsize default 1), L774 (is_cycled default False)
EVENTNERF_ARG_DEFAULTS = {"testskip": "8", "trainskip": "1", "winsize": "1", "is_cycled": "False"}


# ---------------------------------------------------------------- IncEventGS
def inceventgs_chunks(raw: np.ndarray, poses_ts: np.ndarray, numpy2: bool) -> list[np.ndarray]:
    """Events of image i = 1 .. N - 1 as ReplicaEventDataset hands them out.

    IncEventGS datasets/dataset.py L378-382 (float64 slice [ts_0 - dt,
    ts_last + dt), then astype float32), L133-139 (get_event_chunk: lower <= t <
    upper) called at L458 with poses_ts[i - 1], poses_ts[i] (float64 scalars).
    A float32 array against a float64 scalar compares in float64 under NumPy 2
    and in float32 under NumPy 1's value-based casting: both are emulated."""
    dt = poses_ts[1] - poses_ts[0]
    keep = (raw[:, 2] >= poses_ts[0] - dt) & (raw[:, 2] < poses_ts[-1] + dt)
    ev = raw[keep].astype(np.float32)
    t = ev[:, 2].astype(np.float64) if numpy2 else ev[:, 2]
    cast = (lambda v: v) if numpy2 else np.float32
    return [ev[(t >= cast(poses_ts[i - 1])) & (t < cast(poses_ts[i]))] for i in range(1, len(poses_ts))]


# ---------------------------------------------------------------- E2GS / E2NeRF
def e2gs_test_entries(frames: list) -> list:
    """E2GS scene/dataset_readers.py L272 (readNCamerasFromTransforms iterates
    frames[::2]), used for transform_test.json at L316."""
    return frames[::2]


def e2nerf_test_entries(frames: list) -> list:
    """E2NeRF load_blender.py L60-64: frames[0:200:1], image ./test/r_{count}.png."""
    return frames[0:200:1]


# ---------------------------------------------------------------- EvDeblurNeRF
def evdeblurnerf_event_times(t_file: np.ndarray, unit: str) -> np.ndarray:
    """EvDeblurNeRF utils/events.py L32-37: times scaled to us (utils/misc.py
    L108-110 convert_unit), made integers when they all are (misc.py L66-84)."""
    scale = 10 ** ({"us": -6, "ns": -9}[unit] + 6)
    t = t_file * scale
    if np.issubdtype(t.dtype, np.integer) or np.all(np.int32(t) == t):
        t = np.round(t).astype(np.int64)
    return t


def evdeblurnerf_edi_events(ev_t: np.ndarray, start: float, end: float, steps: int = 5) -> tuple[int, int]:
    """Index range of the events the EDI prior sums for one blurred image:
    data/loader_events.py L106-121 (linspace(start, end, steps); searchsorted
    left at each step, right at the next: [start, end] with the end included)."""
    tms = np.linspace(start, end, steps)
    return int(np.searchsorted(ev_t, tms[0], "left")), int(np.searchsorted(ev_t, tms[-1], "right"))


# ---------------------------------------------------------------- Event-3DGS
def event3dgs_index_range(n_views: int) -> range:
    """Event-3DGS train.py L118 (--event: index = randint(2, N - 4), inclusive)
    and L128-131 (positions 5, 25, 45, 65, 85 replaced by the one before)."""
    return range(2, n_views - 4 + 1)


# ================================================================ pure checks
def _hard_frames() -> tuple[np.ndarray, np.ndarray]:
    """30 fps frames (33333/33334 us steps) and events on, just before and just
    after every frame time: the boundary cases of a float time axis."""
    t_frames = 7_000_123 + np.round(np.arange(12) * 1e6 / 30).astype(np.int64)
    ev_t = np.unique(np.concatenate([t_frames[:-1], t_frames[1:] - 1, t_frames[:-1] + 1,
                                     (t_frames[:-1] + t_frames[1:]) // 2]))
    return t_frames, ev_t


def _gs2e_window_slices(t_frames, ev_t):
    w = compute_windows(t_frames, np.zeros(len(t_frames)), ev_t, (int(t_frames[0]), int(t_frames[-1])))
    return [(int(r.inter_i0), int(r.inter_i1)) for r in w.itertuples() if r.inter_covered]


def _eventnerf_selections(ts, n, winsize=1):
    return [(s, e) for _, s, e in eventnerf_samplers(ts, n, 1, winsize, winsize)]


def test_eventnerf_loader_windows_equal_gs2e_windows():
    t_frames, ev_t = _hard_frames()
    n = len(t_frames)
    ev = Events(ev_t, np.zeros(len(ev_t), np.uint16), np.zeros(len(ev_t), np.uint16), np.ones(len(ev_t), np.uint8))
    arrays = loader_events(ev, t_frames, "test")
    ts = arrays["t"]
    assert ts.max() == loader_bounds_s(n, (t_frames[-1] - t_frames[0]) * 1e-6)[-1] and arrays["p"][-1] == 0
    assert np.all(np.diff(ts) >= 0)  # searchsorted needs sorted times
    gs2e = _gs2e_window_slices(t_frames, ev_t)
    # winsize 1: sampler i holds gs2e's window of frame i (windows from view 2 on)
    assert _eventnerf_selections(ts, n) == gs2e[1:]
    # winsize 3: the union of gs2e's windows i - 2 .. i
    assert _eventnerf_selections(ts, n, 3) == [(gs2e[i - 3][0], gs2e[i - 1][1]) for i in range(4, n)]
    assert np.abs(ts[:-1] - (ev_t - t_frames[0]) * 1e-6).max() < 1e-6  # moved by less than 1 us
    # the plain offset, with t.max() the last event, misses boundary events
    naive = (ev_t - t_frames[0]) * 1e-6
    assert _eventnerf_selections(naive, n) != gs2e[1:]


def test_inceventgs_windows_equal_gs2e_windows_in_both_numpy_semantics():
    t_frames, ev_t = _hard_frames()
    t_frames = np.concatenate([t_frames, t_frames[-1] + 20_000_000 + np.arange(4) * 33_333])  # past 16 s
    ev_t = np.unique(np.concatenate([ev_t, t_frames[-4:-1], t_frames[-3:] - 1]))
    poses_ts = pose_times_s(t_frames)
    read = np.array([float(s) for s in "".join(f"{float(v)!r}\n" for v in poses_ts).split()])  # np.loadtxt
    assert np.array_equal(read, poses_ts.astype(np.float64))
    raw = np.stack([np.zeros(len(ev_t)), np.zeros(len(ev_t)),
                    times_in_loader_windows(ev_t, t_frames, poses_ts).astype(np.float64), np.ones(len(ev_t))], 1)
    gs2e = _gs2e_window_slices(t_frames, ev_t)
    for numpy2 in (True, False):
        chunks = inceventgs_chunks(raw, read, numpy2)
        assert [len(c) for c in chunks] == [b - a for a, b in gs2e]
    # the former poses_ts "%.6f" with float64 offsets disagrees at frame boundaries
    old = np.stack([raw[:, 0], raw[:, 1], (ev_t - t_frames[0]) * 1e-6, raw[:, 3]], 1)
    old_ts = np.array([float(f"{v:.6f}") for v in (t_frames - t_frames[0]) * 1e-6])
    assert [len(c) for c in inceventgs_chunks(old, old_ts, True)] != [b - a for a, b in gs2e]


def test_eventnerf_winsize_leaves_training_windows_or_names_the_key():
    assert choose_winsize(200, None) == 50        # EventNeRF's own configs' 50
    assert choose_winsize(9, None) == 4           # short trajectories: half the views
    assert choose_winsize(3, None) == 1
    for n in (3, 9, 200):
        assert len(eventnerf_samplers(np.arange(5.0), n, 1, choose_winsize(n, None), 1)) >= (n - 1) // 2
    assert choose_winsize(9, 7) == 7
    with pytest.raises(ConfigError) as exc:
        choose_winsize(9, 100)
    msg = str(exc.value)
    assert "\n" not in msg and "export.eventnerf_winsize" in msg and "at most 7" in msg
    # EventNeRF's own winsize 100 with is_cycled = False: no sampler at all on 9 views
    assert eventnerf_samplers(np.arange(5.0), 9, 1, 100, 100) == []


def test_loader_conventions_fail_on_the_old_layouts():
    """The re-implemented lines reproduce the reported failures."""
    # EventNeRF: testskip 8 keeps one of 3 validation views, and no sampler
    assert eventnerf_samplers(np.arange(5.0), 3, int(EVENTNERF_ARG_DEFAULTS["testskip"]), 1, 1) == []
    # E2GS: half of a plain test list vanishes
    plain = [{"v": k} for k in range(5)]
    assert [f["v"] for f in e2gs_test_entries(plain)] == [0, 2, 4]
    doubled = [f for f in plain for _ in range(2)]
    assert e2gs_test_entries(doubled) == plain and len(e2nerf_test_entries(doubled)) == 10
    # EvDeblurNeRF: integer us stay integers; the EDI window includes its end
    t = np.array([10, 20, 30, 40], np.int64)
    assert evdeblurnerf_event_times(t, "us").dtype == np.int64
    assert evdeblurnerf_edi_events(t, 20, 40) == (1, 4)
    assert event3dgs_index_range(7) == range(2, 4)
