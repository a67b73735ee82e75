"""The few loader lines each export depends on, re-implemented from the
methods' public code (each helper cites the repository, file and lines it
follows), and fast checks of gs2e's loader-time placement against them.
tests/test_export_formats.py runs the same helpers on real exports.

Sources (snapshots read with the search tools):
r00tman/EventNeRF 44297dd, deguchihiroyuki/E2GS 68e5614, iCVTEAM/E2NeRF 487fec1,
uzh-rpg/EvDeblurNeRF 4111020, WU-CVGL/IncEventGS 28d070f, lanpokn/Event-3DGS d6d12b8.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events
from gs2e.export.common import ExportOut, times_in_loader_windows
from gs2e.export.eventnerf import choose_winsize, loader_bounds_s, loader_events
from gs2e.export.inceventgs import floored_ray_error_px, pose_times_s
from gs2e.export.settings import ExportSettings
from gs2e.export.windows import compute_windows, exposure_bounds_us


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


def eventnerf_split_files(split_dir) -> tuple[list, list, list]:
    """Sorted pose, intrinsics and rgb files of a split: data_loader_split.py
    L14-24 (find_files: sorted glob), L40-41, L58 (skip = 1)."""
    return tuple(sorted(str(p) for p in (split_dir / sub).glob(pat))
                 for sub, pat in (("pose", "*.txt"), ("intrinsics", "*.txt"), ("rgb", "*.png")))


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


def inceventgs_floored_rays(H: int, W: int, fx: float, fy: float, cx: float, cy: float,
                            downsample: int = 1) -> np.ndarray:
    """(H, W, 3) ray directions of the depth initialisation / densification.

    IncEventGS datasets/dataset.py L112-115 (BaseDataset: fx, fy, cx, cy
    floor-divided by data.downsample) and datasets/utils.py L31-32, L51-52
    (get_camera_rays, OpenCV: pixel index (i, j) -> ((i - cx)/fx, (j - cy)/fy, 1))."""
    fx, fy, cx, cy = (v // downsample for v in (fx, fy, cx, cy))
    i, j = np.meshgrid(np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32), indexing="xy")
    return np.stack([(i - cx) / fx, (j - cy) / fy, np.ones_like(i)], -1)


# ---------------------------------------------------------------- E2GS / E2NeRF
def e2gs_test_entries(frames: list) -> list:
    """E2GS scene/dataset_readers.py L272 (readNCamerasFromTransforms iterates
    frames[::2]), used for transform_test.json at L316."""
    return frames[::2]


def e2nerf_test_entries(frames: list) -> list:
    """E2NeRF load_blender.py L60-64: frames[0:200:1], image ./test/r_{count}.png."""
    return frames[0:200:1]


def e2gs_novel_test_cameras(root) -> list[tuple[np.ndarray, tuple[int, int]]]:
    """(camera-to-world, (width, height)) of each test camera of E2GS's
    render_novel.py (Scene mode "novel", scene/__init__.py L48-50):
    scene/dataset_readers.py L450-454 and L483-522 (transform_test.json
    frames[1::2], transform_matrix entry 1, OpenGL -> COLMAP axes; the image,
    opened only for its size, is always <scene>/images/r_0.png)."""
    from PIL import Image

    frames = json.loads((root / "transform_test.json").read_text())["frames"]
    out = []
    for fr in frames[1::2]:
        c2w = np.array(fr["transform_matrix"])[1]
        c2w[:3, 1:3] *= -1
        with Image.open(root / "images/r_0.png") as im:
            out.append((c2w, im.size))
    return out


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


def evdeblurnerf_edi_subintervals(ev_t: np.ndarray, start: float, end: float,
                                  steps: int = 9) -> list[tuple[int, int]]:
    """events[a:b] of each of the EDI prior's steps - 1 brightness increments:
    data/loader_events.py L107 (linspace), L111-112 (searchsorted left, right),
    L118-121 (increment j: left[j] .. right[j + 1]); steps = pts0_edi_steps,
    default 9 (options.py L171)."""
    tms = np.linspace(start, end, steps)
    left, right = np.searchsorted(ev_t, tms, "left"), np.searchsorted(ev_t, tms, "right")
    return [(int(left[j]), int(right[j + 1])) for j in range(steps - 1)]


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


def _eventnerf_selections(ts, n, winsize=1, lead=0):
    """(start, end) of the samplers of a split whose first ``lead`` views are
    lead-in copies (max_winsize = lead, so the first sampler is real view 1)."""
    return [(s, e) for _, s, e in eventnerf_samplers(ts, n, 1, max(lead, winsize), winsize)]


def test_eventnerf_loader_windows_equal_gs2e_windows():
    t_frames, ev_t = _hard_frames()
    n = len(t_frames)
    ev = Events(ev_t, np.zeros(len(ev_t), np.uint16), np.zeros(len(ev_t), np.uint16), np.ones(len(ev_t), np.uint8))
    step = 1 / 30
    arrays = loader_events(ev, t_frames, 0, step, "test")
    ts = arrays["t"]
    assert ts.max() == loader_bounds_s(n, (n - 1) * step)[-1] and arrays["p"][-1] == 0
    assert np.all(np.diff(ts) >= 0)  # searchsorted needs sorted times
    gs2e = _gs2e_window_slices(t_frames, ev_t)
    # winsize 1: sampler i holds gs2e's window of frame i (windows from view 2 on)
    assert _eventnerf_selections(ts, n) == gs2e[1:]
    # winsize 3: the union of gs2e's windows i - 2 .. i
    assert _eventnerf_selections(ts, n, 3) == [(gs2e[i - 3][0], gs2e[i - 1][1]) for i in range(4, n)]
    assert np.abs(ts[:-1] - (ev_t - t_frames[0]) * 1e-6).max() < 1e-6  # even frames: moved by < 1 us
    # the plain offset, with t.max() the last event, misses boundary events
    naive = (ev_t - t_frames[0]) * 1e-6
    assert _eventnerf_selections(naive, n) != gs2e[1:]


def test_eventnerf_windows_across_held_out_frames_and_lead_in():
    """Views 2 and 6 held out, 3 lead-in copies: every window of 1..3 views
    from the second real view on holds exactly gs2e's events between them."""
    t_frames, ev_t = _hard_frames()
    real = np.delete(np.arange(len(t_frames)), [2, 6])
    ev = Events(ev_t, np.zeros(len(ev_t), np.uint16), np.zeros(len(ev_t), np.uint16), np.ones(len(ev_t), np.uint8))
    sel = (ev_t >= t_frames[real[0]]) & (ev_t < t_frames[real[-1]])
    lead = 3
    arrays = loader_events(Events(ev.t[sel], ev.x[sel], ev.y[sel], ev.p[sel]), t_frames[real], lead, 1 / 30, "t")
    n = lead + len(real)
    views_t = np.concatenate([np.repeat(t_frames[real[:1]], lead), t_frames[real]])
    for w in (1, 2, 3):
        got = eventnerf_samplers(arrays["t"], n, 1, lead, w)
        assert [i for i, _, _ in got] == list(range(1 + lead, n))  # every real view but the first
        want = [tuple(np.searchsorted(ev_t[sel], [views_t[i - w], views_t[i]])) for i in range(1 + lead, n)]
        assert [(a, b) for _, a, b in got] == want


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


def test_eventnerf_winsize_fits_the_train_split_or_names_the_key():
    assert choose_winsize(200, None) == 50        # EventNeRF's own configs' 50
    assert choose_winsize(9, None) == 8           # short trajectories: windows up to the whole split
    assert choose_winsize(2, None) == 1
    assert choose_winsize(9, 8) == 8
    with pytest.raises(ConfigError) as exc:
        choose_winsize(9, 100)
    msg = str(exc.value)
    assert "\n" not in msg and "export.eventnerf_winsize" in msg and "at most 8" in msg
    # EventNeRF's own winsize 100 with is_cycled = False and no lead-in: no sampler at all on 9 views
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


# ================================================================ exports of a tiny in-memory source
class _TinySource:
    """What the exporters read of a trajectory, in memory: the 12 frames of
    ``_hard_frames`` (8x6 pixels, fx = fy = 10.46, principal point centred),
    20001 us exposures (odd: the EDI prior's mid-step is an integer time when
    its end is exp_t1_us - 1), events on, just before and just after every frame time
    and exposure bound (both polarities, repeated pixels), a straight camera
    path and a few scene points; no depth."""

    width, height = 8, 6
    events_file = "tiny/events.h5"
    focal = 10.46
    cfa = None  # luminance events (events.h5's metadata records no colour filter)

    def __init__(self) -> None:
        t, ev_t = _hard_frames()
        ea, eb = exposure_bounds_us(t, np.full(len(t), 20_001.0), int(t[0]), int(t[-1]))
        ev_t = np.unique(np.concatenate([ev_t, ea, eb, eb - 1, ea + 1]))
        ev_t = ev_t[ev_t < t[-1]]
        m = np.arange(len(ev_t))
        self.ev = Events(ev_t, (m % self.width).astype(np.uint16), ((m // 3) % self.height).astype(np.uint16),
                         (m % 2).astype(np.uint8))
        self.frames = pd.DataFrame({"t_us": t})
        self.windows = compute_windows(t, np.full(len(t), 20_001.0), ev_t, (int(t[0]), int(t[-1])))

    def covered_frames(self) -> np.ndarray:
        return np.arange(len(self.frames))

    def K(self, frame: int = 0) -> np.ndarray:
        return np.array([[self.focal, 0, self.width / 2], [0, self.focal, self.height / 2], [0, 0, 1.0]])

    def poses_at(self, t_us) -> np.ndarray:
        t = np.asarray(t_us, np.float64)
        out = np.tile(np.eye(4), (len(t), 1, 1))
        out[:, 0, 3] = (t - self.frames["t_us"].iloc[0]) * 1e-6
        out[:, 2, 3] = -2.0
        return out

    def c2w(self, frames) -> np.ndarray:
        return self.poses_at(self.frames["t_us"].to_numpy()[np.asarray(frames, int)])

    def image(self, kind: str, frame: int) -> np.ndarray:
        return np.full((self.height, self.width, 3), (20 * int(frame) + (kind == "blur")) % 256, np.uint8)

    def events(self, t0_us=None, t1_us=None) -> Events:
        a, b = (0, len(self.ev)) if t0_us is None else np.searchsorted(self.ev.t, [t0_us, t1_us])
        return Events(self.ev.t[a:b], self.ev.x[a:b], self.ev.y[a:b], self.ev.p[a:b])

    def depth(self, frame: int) -> np.ndarray:
        raise InputError("no depth")

    def depth_range(self, frames) -> np.ndarray:
        return np.tile([1.0, 5.0], (len(frames), 1))

    def points(self) -> tuple[np.ndarray, np.ndarray]:
        xyz = np.array([[0.0, 0.0, 0.0], [0.1, 0.2, 0.3], [-0.2, 0.1, 0.4]])
        return xyz, np.full((3, 3), 128, np.uint8)


EXPORT_CFG = ExportSettings.defaults(eventnerf_fit="pad", eventnerf_holdout_every=4, eventnerf_winsize=None,
                                     e2nerf_loader="e2gs", evdeblurnerf_llffhold=4,
                                     evdeblurnerf_pose_rate_hz=1000.0, inceventgs_jpeg_quality=95)


def _export(fn, fmt: str, tmp_path, src=None) -> tuple:
    src = src or _TinySource()
    out = ExportOut(tmp_path / fmt, fmt)
    fn(src, out, EXPORT_CFG)
    return src, out.root, out.manifest


def test_eventnerf_reads_colour_events_only_in_its_own_bayer_phase(tmp_path):
    """RGGB events: is_colored = True where the pad keeps the pattern's phase
    (an even offset); an odd offset, or another pattern, is an error naming the file."""
    from gs2e.common.errors import InputError
    from gs2e.export.eventnerf import export_eventnerf

    class Colour(_TinySource):
        width, height, cfa = 10, 8, "RGGB"  # pads by (168, 126): even

    _, root, _ = _export(export_eventnerf, "eventnerf", tmp_path / "even", Colour())
    assert eventnerf_config((root / "eventnerf.txt").read_text())["is_colored"] == "True"
    odd = _TinySource()
    odd.cfa = "RGGB"  # 8x6 pads by (169, 127): the pattern would shift
    with pytest.raises(InputError, match="tiny/events.h5.*shifts the RGGB pattern"):
        _export(export_eventnerf, "eventnerf", tmp_path / "odd", odd)
    bggr = Colour()
    bggr.cfa = "BGGR"
    with pytest.raises(InputError, match="reads RGGB only"):
        _export(export_eventnerf, "eventnerf", tmp_path / "bggr", bggr)


def test_e2gs_render_novel_reads_the_export(tmp_path):
    """render_novel.py's test cameras open images/r_0.png (for its size): it is
    written, at the frames' size, and the cameras are gs2e's test views."""
    from gs2e.export.e2nerf import export_e2nerf

    src, root, man = _export(export_e2nerf, "e2nerf", tmp_path)
    cams = e2gs_novel_test_cameras(root)
    assert [size for _, size in cams] == [(src.width, src.height)] * len(man["gs2e_frames"])
    for (c2w, _), i in zip(cams, man["gs2e_frames"]):
        np.testing.assert_allclose(c2w, src.c2w([i])[0], atol=1e-12)
    # images/ holds the COLMAP model's images r_{2k}.png: the blurred training frames
    for k in range(len(man["gs2e_frames"])):
        assert (root / f"images/r_{2 * k}.png").read_bytes() == (root / f"train/r_{2 * k}.png").read_bytes()


def test_evdeblurnerf_edi_prior_sums_exactly_the_exposure_window(tmp_path):
    """Events stamped exactly exp_t1_us (the source has one at every exposure
    end) stay out of the EDI prior, and no event is summed into two of its
    sub-intervals with the default pts0_edi_steps."""
    import h5py

    from gs2e.export.evdeblurnerf import export_evdeblurnerf

    src, root, man = _export(export_evdeblurnerf, "evdeblurnerf", tmp_path)
    tms = np.load(root / "images_1/timestamps.npz")
    with h5py.File(root / "events.h5", "r") as f:
        t_us = evdeblurnerf_event_times(f["t"][:], "us")
    w, origin = src.windows, man["time_origin_us"]
    blurred = [k for k in range(len(man["gs2e_frames"])) if k not in man["sharp_images"]]
    at_end = 0
    for k in blurred:
        i = man["gs2e_frames"][k]
        start, end = tms["timestamps_start"][k], tms["timestamps_end"][k]
        assert start < end and start > 0                                   # loader_events.py L103
        at_end += int((t_us + origin == w["exp_t1_us"].iloc[i]).sum())
        a, b = evdeblurnerf_edi_events(t_us, start, end)
        assert (a, b) == (w["exp_i0"].iloc[i], w["exp_i1"].iloc[i])
        subs = evdeblurnerf_edi_subintervals(t_us, start, end)
        assert sum(hi - lo for lo, hi in subs) == b - a and subs[0][0] == a and subs[-1][1] == b
    assert at_end >= len(blurred) - 1  # events stamped exactly exp_t1_us were there to be excluded
    # the former end (exp_t1_us itself) adds the events stamped exactly there
    i = man["gs2e_frames"][blurred[0]]
    a, b = evdeblurnerf_edi_events(t_us, tms["timestamps_start"][blurred[0]], w["exp_t1_us"].iloc[i] - origin)
    assert b - a > w["exp_i1"].iloc[i] - w["exp_i0"].iloc[i]


def test_eventnerf_holds_out_views_and_every_training_frame_ends_a_window(tmp_path):
    """Validation / test samplers are exactly the held-out frames, never
    training views; training samplers end at every training frame but the
    first; each window holds gs2e's events between its two views' frames."""
    from gs2e.export.eventnerf import export_eventnerf

    src, root, man = _export(export_eventnerf, "eventnerf", tmp_path)
    cfg = {**EVENTNERF_ARG_DEFAULTS, **eventnerf_config((root / "eventnerf.txt").read_text())}
    held = man["heldout_frames"]
    t_frames = src.frames["t_us"].to_numpy()
    train = [i for i in range(len(t_frames)) if i not in held]
    assert held == [3, 7] and cfg["is_cycled"] == "False"
    for split in ("train", "validation", "test"):
        info = man["splits"][split]
        poses, intr, rgbs = eventnerf_split_files(root / split)
        views = info["gs2e_frames"]
        assert len(poses) == len(intr) == len(rgbs) == len(views)
        max_win = int(cfg["winsize"]) if split == "train" else 1       # ddp_train_nerf.py L441, L447
        skip = int(cfg["trainskip"] if split == "train" else cfg["testskip"])
        z = np.load(root / split / "events" / "events.npz")
        ev_t = src.events(t_frames[views[0]], t_frames[views[-1]]).t
        for w in range(1, max_win + 1):
            samplers = eventnerf_samplers(z["t"], len(poses), skip, max_win, w)
            ends = [views[i] for i, _, _ in samplers]
            assert ends == (train[1:] if split == "train" else held)
            for i, a, b in samplers:
                assert (a, b) == tuple(np.searchsorted(ev_t, t_frames[[views[i - w], views[i]]]))
                c2w = np.loadtxt(poses[i - w])                       # the window's start pose
                back = c2w[:3, 3] / man["normalisation"]["scale"] - man["normalisation"]["translate"]
                np.testing.assert_allclose(back, src.c2w([views[i - w]])[0][:3, 3], atol=1e-9)
    assert set(held).isdisjoint(man["splits"]["train"]["gs2e_frames"])


def test_inceventgs_floored_intrinsics_error_is_stated(tmp_path):
    """The warning and manifest give how far IncEventGS's floored rays miss
    their pixel (its own lines re-implemented), and integers give none."""
    from gs2e.export.inceventgs import export_inceventgs

    src, root, man = _export(export_inceventgs, "inceventgs", tmp_path)
    H, W, K = src.height, src.width, src.K()
    d = inceventgs_floored_rays(H, W, K[0, 0], K[1, 1], K[0, 2], K[1, 2]).astype(np.float64)
    u, v = K[0, 0] * d[..., 0] + K[0, 2], K[1, 1] * d[..., 1] + K[1, 2]  # exact K (dataset.py L363-369)
    i, j = np.meshgrid(np.arange(W), np.arange(H), indexing="xy")
    miss = float(np.hypot(u - i, v - j).max())
    assert miss > 0.01 and man["intrinsics_floor_error_px"] == pytest.approx(miss, rel=1e-5)
    assert any(f"{miss:.3f} px" in m and "L112-115" in m for m in man["warnings"])
    assert floored_ray_error_px(np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]]), W, H) == 0.0
    assert inceventgs_floored_rays(H, W, 10.0, 10.0, 4.0, 3.0)[0, 0, 0] == pytest.approx(-0.4)
