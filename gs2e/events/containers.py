"""Event containers other tools open: AEDAT4, Prophesee RAW (EVT2/EVT3) and DAT,
read and written through faery (Rust-backed, maintained; chosen on
``benchmarks/bench_event_io.py``: the one library that reads and writes all of
them, with identical events back and the sensor size in every header).

What gs2e writes (events time-sorted; t absolute microseconds, >= 0):

``aedat4`` (``.aedat4``, iniVation DV)
    One event stream (id 0, type ``EVTS``) with ``sizeX``/``sizeY`` = sensor
    width/height and ``source`` = gs2e; LZ4 packets of at most
    :data:`AEDAT4_PACKET` events; t is stored absolute (int64 us).
``evt2`` (``.raw``, Prophesee EVT 2.0)
    Header ``% evt 2.0``, ``% format EVT2;width=W;height=H``, ``% geometry WxH``
    and ``% t0 T`` (the first event's absolute time: faery adds it back, tools
    that ignore the line see times from the first event). 4 bytes per event;
    sensors up to 2048 x 2048.
``dat`` (``.dat``, Prophesee DAT 2, CD events)
    Header ``% Version 2``, ``% Width``, ``% Height``, ``% T0`` (as above);
    8 bytes per event; times from the first event below 2^32 us (71.6 min).

EVT3 is read (real Prophesee cameras write it) but not written: faery 0.7.1's
EVT3 decoder counts a 2^24 us time-high wrap only when time-high steps from
0xFFF to 0x000, which a camera always writes but faery's encoder skips over
when no event falls in those two 4.1 ms slots, so a written file with a
quiet gap across a wrap reads back with wrong times (measured in the benchmark).

Readers take the sensor size from the header and the version of a ``.raw``
from its ``% evt`` line; anything unreadable is an :class:`InputError` naming
the file.
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path

import numpy as np

from gs2e.common.atomic import atomic_path
from gs2e.common.errors import InputError
from gs2e.events.models import Events

# container name (config ``events.containers``) -> file suffix
CONTAINERS = {"aedat4": ".aedat4", "evt2": ".raw", "dat": ".dat"}
# suffix -> container written by events-convert
SUFFIX_CONTAINER = {v: k for k, v in CONTAINERS.items()}
READ_SUFFIXES = (".aedat4", ".raw", ".dat")
# AEDAT4 packet size: DV's own recorder writes packets of thousands of events;
# one multi-million-event packet would have to be decompressed whole by readers
AEDAT4_PACKET = 1 << 16
EVT2_MAX_SIZE = 2048          # 11-bit x and y
DAT_MAX_SIZE = 1 << 14        # 14-bit x and y
DAT_MAX_SPAN_US = 1 << 32     # 32-bit timestamps (faery does not unwrap them)

_FAERY_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])
_DAT_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("payload", "u1")])


def container_limits(kind: str, width: int, height: int) -> str | None:
    """Why ``kind`` cannot hold a ``width`` x ``height`` sensor, or None if it can."""
    if kind not in CONTAINERS:
        return f"unknown container '{kind}' (one of {', '.join(CONTAINERS)})"
    if width < 1 or height < 1:
        return f"sensor size {width}x{height} is empty"
    limit = {"evt2": EVT2_MAX_SIZE, "dat": DAT_MAX_SIZE}.get(kind)
    if limit is not None and (width > limit or height > limit):
        return f"{kind} holds sensors up to {limit}x{limit}, got {width}x{height}"
    return None


class ContainerWriter:
    """Streaming writer of one container file (use as a context manager).

    ``append(events)`` takes time-sorted :class:`Events` batches (absolute us,
    t >= 0, x < width, y < height; unsorted input is a ValueError, data the
    format cannot hold an InputError); the file appears at ``path`` only when
    the context exits without error (a temporary beside it is removed otherwise).

    Parameters
    ----------
    path : str or PathLike
        Output file.
    kind : str
        ``aedat4``, ``evt2`` or ``dat`` (:data:`CONTAINERS`).
    width, height : int
        Sensor size in pixels, written to the header.
    """

    def __init__(self, path: str | os.PathLike, kind: str, width: int, height: int):
        self.path, self.kind = Path(path), kind
        self.width, self.height = int(width), int(height)
        why = container_limits(kind, self.width, self.height)
        if why:
            raise ValueError(f"{self.path}: {why}")
        self.n = 0
        self.t_first: int | None = None
        self.t_last: int | None = None
        self._stack = contextlib.ExitStack()

    def __enter__(self) -> "ContainerWriter":
        import faery

        try:
            tmp = self._stack.enter_context(atomic_path(self.path))
            dims = (self.width, self.height)
            if self.kind == "aedat4":
                self._enc = faery.aedat.Encoder(tmp, aedat4_description(*dims), faery.aedat.LZ4_DEFAULT)
            elif self.kind == "evt2":
                # zero_t0: the first event's time goes to the header, so any
                # absolute time fits the format's 34-bit clock
                self._enc = faery.evt.Encoder(tmp, "evt2", True, dims, True)
            else:
                self._enc = faery.dat.Encoder(tmp, "dat2", "cd", True, dims)
            self._stack.enter_context(self._enc)
        except BaseException:
            self._stack.close()
            raise
        return self

    def append(self, ev: Events) -> None:
        """Write the next time-sorted batch (absolute us)."""
        n = len(ev)
        if n == 0:
            return
        t = np.asarray(ev.t, np.int64)
        # checked here, not left to faery: its EVT/DAT encoders subtract the
        # first time as unsigned, so an earlier event would wrap to ~2^64 us
        if (self.t_last is not None and t[0] < self.t_last) or np.any(t[1:] < t[:-1]):
            raise ValueError(f"{self.path}: events must be appended in time order")
        # what the data asks of the format: InputError, like any input that does not fit
        if t[0] < 0:
            raise InputError(f"{self.path}: {self.kind} cannot store negative times (t = {t[0]} us)")
        if self.t_first is None:
            self.t_first = int(t[0])
        if self.kind == "dat" and t[-1] - self.t_first >= DAT_MAX_SPAN_US:
            raise InputError(f"{self.path}: DAT times span at most 2^32 us from the first event, "
                             f"got {t[-1] - self.t_first} us")
        if int(ev.x.max()) >= self.width or int(ev.y.max()) >= self.height:
            raise InputError(f"{self.path}: event at x={int(ev.x.max())} or y={int(ev.y.max())} "
                             f"outside the {self.width}x{self.height} sensor")
        a = np.empty(n, _DAT_DTYPE if self.kind == "dat" else _FAERY_DTYPE)
        a["t"], a["x"], a["y"] = t, ev.x, ev.y
        a["payload" if self.kind == "dat" else "on"] = ev.p != 0
        if self.kind == "aedat4":
            for i in range(0, n, AEDAT4_PACKET):
                self._enc.write(0, a[i:i + AEDAT4_PACKET])
        elif self.kind == "evt2":
            self._enc.write({"events": a})
        else:
            self._enc.write(a)
        self.n += n
        self.t_last = int(t[-1])

    def __exit__(self, exc_type, exc, tb):
        return self._stack.__exit__(exc_type, exc, tb)


def write_container(path: str | os.PathLike, kind: str, ev: Events, width: int, height: int) -> None:
    """Write all of ``ev`` (time-sorted, absolute us) to one container file, atomically."""
    with ContainerWriter(path, kind, width, height) as w:
        w.append(ev)


def aedat4_description(width: int, height: int):
    """The AEDAT4 header (DV's IOHeader info tree) of one event stream."""
    import faery

    A, N = faery.aedat.DescriptionAttribute, faery.aedat.DescriptionNode
    root = "/mainloop/Recorder/outInfo/"
    info = N("info", f"{root}0/info/",
             {"sizeX": A("int", width), "sizeY": A("int", height), "source": A("string", "gs2e")}, [])
    stream = N("0", f"{root}0/", {"compression": A("string", "LZ4"),
                                   "originalOutputName": A("string", "events"),
                                   "typeIdentifier": A("string", "EVTS")}, [info])
    return [N("outInfo", root, {}, [stream])]


# ---------------------------------------------------------------- reading
# Pixel arrays of the cameras a recording's header may name, for headers that
# carry no width/height (many Prophesee EVK recordings): (name pattern matched
# in the header's plugin_name / sensor_generation / sensor / camera values,
# (width, height), source). The most specific pattern first.
_PSEE = "docs.prophesee.ai/stable/hw/"
CAMERA_SIZES: tuple[tuple[str, tuple[int, int], str], ...] = (
    ("genx320", (320, 320), _PSEE + "sensors/genx320.html (Prophesee GenX320)"),
    ("imx636", (1280, 720), _PSEE + "sensors/imx636.html (Sony IMX636 HD, EVK4)"),
    ("imx646", (1280, 720), "Sony IMX646 product brief (1280x720, as IMX636)"),
    ("gen41", (1280, 720), _PSEE + "sensors/gen41.html (Prophesee Gen4.1 HD, EVK3-HD)"),
    ("gen4", (1280, 720), "Prophesee Gen4 HD (Finateu et al., ISSCC 2020: 1280x720)"),
    ("gen31", (640, 480), _PSEE + "sensors/gen31.html (Prophesee Gen3.1 VGA)"),
    ("gen3", (640, 480), "Prophesee Gen3 VGA (PPS3MVCD datasheet: 640x480)"),
    ("davis346", (346, 260), "iniVation DAVIS346 datasheet"),
    ("davis240", (240, 180), "iniVation DAVIS240 datasheet"),
    ("dvxplorerlite", (320, 240), "iniVation DVXplorer Lite datasheet"),
    ("dvxplorermini", (640, 480), "iniVation DVXplorer Mini datasheet"),
    ("dvxplorer", (640, 480), "iniVation DVXplorer datasheet"),
    ("dvs128", (128, 128), "iniVation DVS128 (Lichtsteiner et al., JSSC 2008)"),
)
_CAMERA_KEYS = ("plugin_name", "sensor_generation", "sensor_name", "sensor", "camera", "camera_type")


def camera_size(header: dict[str, str]) -> tuple[int, int, str] | None:
    """(width, height, source) of the camera a file header names, or None.

    Reads the ``plugin_name`` (e.g. ``hal_plugin_gen3_fx3``), ``sensor_generation``
    (``4.1``), ``sensor_name``, ``sensor``, ``camera`` values, ignoring case,
    ``_``, ``.``, ``-`` and spaces; :data:`CAMERA_SIZES` lists what is known.
    """
    for key in _CAMERA_KEYS:
        if key not in header:
            continue
        v = re.sub(r"[\s_.\-]", "", header[key].lower())
        if key == "sensor_generation":
            v = "gen" + v
        for pattern, (w, h), source in CAMERA_SIZES:
            if pattern in v:
                return w, h, f"{key} '{header[key]}': {source}"
    return None


def read_container(path: str | os.PathLike,
                   size: tuple[int, int] | None = None) -> tuple[Events, tuple[int, int] | None]:
    """Events of an AEDAT4 (first event stream), Prophesee RAW (EVT2/EVT3) or
    DAT (CD events) file, picked by suffix.

    The sensor size comes from the header, else from the camera the header
    names (:func:`camera_size`), else from ``size`` = (width, height) (the
    user's); a RAW file with none of these is a one-line error saying so.

    Returns
    -------
    events : Events
        Time-sorted (stable: a file's order among equal times is kept);
        t absolute int64 us (RAW/DAT: plus the header's ``% t0``, if any).
    shape : (height, width) or None
        The sensor size from the header; None only for a DAT file without one.
    """
    path = Path(path)
    suf = path.suffix.lower()
    if suf not in READ_SUFFIXES:
        raise InputError(f"{path}: not an AEDAT4 / RAW / DAT file (suffix {suf or 'none'})")
    if not path.is_file():
        raise InputError(f"{path}: no such event file")
    import faery

    try:
        if suf == ".aedat4":
            label = "AEDAT4"
            a, shape = _read_aedat4(path, faery)
        elif suf == ".raw":
            label = "Prophesee RAW (EVT2/EVT3)"
            a, shape = _read_raw(path, faery, size)
        else:
            label = "Prophesee DAT"
            a, shape = _read_dat(path, faery, size)
    except InputError:
        raise
    except Exception as exc:  # faery reports corrupt input as RuntimeError
        raise InputError(f"{path}: not a readable {label} file ({exc})") from exc
    if a is None or len(a) == 0:
        return Events.empty(), shape
    t = a["t"].astype(np.int64)
    p = (a["payload"] if "payload" in a.dtype.names else a["on"]).astype(bool).astype(np.uint8)
    x, y = a["x"].astype(np.uint16), a["y"].astype(np.uint16)
    if np.any(t[1:] < t[:-1]):  # AEDAT4 packets of several sources may interleave
        o = np.argsort(t, kind="stable")
        t, x, y, p = t[o], x[o], y[o], p[o]
    return Events(t, x, y, p), shape


def _concat(parts: list[np.ndarray]) -> np.ndarray | None:
    return np.concatenate(parts) if parts else None


def _read_aedat4(path: Path, faery):
    with faery.aedat.Decoder(path) as dec:
        tracks = [tr for tr in dec.tracks() if tr.data_type == "events"]
        if not tracks:
            raise InputError(f"{path}: AEDAT4 file has no event stream")
        track = min(tracks, key=lambda tr: tr.id)
        W, H = track.dimensions
        parts = [pk for tr, pk in dec if tr.id == track.id and len(pk)]
    return _concat(parts), (int(H), int(W))


def _header_size(header: dict[str, str]) -> bool:
    """Whether a Prophesee header states the size itself (what faery reads)."""
    fmt = header.get("format", "")
    return ("width=" in fmt and "height=" in fmt) or "geometry" in header or (
        "Width" in header and "Height" in header)


def _size_choice(header: dict[str, str], size: tuple[int, int] | None):
    """(fallback (width, height) or None, where the size comes from: "header",
    the named camera's table entry, "--width/--height", or None if nowhere)."""
    if _header_size(header):
        return None, "header"
    cam = camera_size(header)
    if cam is not None:
        return (cam[0], cam[1]), cam[2]
    if size is not None:
        return (int(size[0]), int(size[1])), "--width/--height"
    return None, None


def size_origin(path: str | os.PathLike, size: tuple[int, int] | None = None) -> str | None:
    """Where the sensor size of a RAW/DAT file whose header states none comes
    from (the named camera, or ``size``); None when the header states it, or
    for other formats."""
    path = Path(path)
    if path.suffix.lower() not in (".raw", ".dat"):
        return None
    origin = _size_choice(_prophesee_header(path)[0], size)[1]
    if origin in (None, "header", "--width/--height"):
        return None if origin == "header" else origin
    return f"the camera the header of {path} names: {origin}"


def _size_fallback(path: Path, header: dict[str, str], size: tuple[int, int] | None):
    """(width, height) for a header without a size: the named camera's, else ``size``."""
    dims, origin = _size_choice(header, size)
    if origin is not None:
        return dims
    named = ", ".join(f"{k} '{header[k]}'" for k in _CAMERA_KEYS if k in header)
    what = (f"names a camera gs2e's table does not know ({named}; gs2e.events.containers."
            "CAMERA_SIZES)" if named else "names no camera")
    raise InputError(f"{path}: the header gives no sensor size and {what}: pass --width and --height")


def _read_raw(path: Path, faery, size: tuple[int, int] | None = None):
    # the version must be in the header; the size may come from the camera it names
    header, _ = _prophesee_header(path)
    with faery.evt.Decoder(path, _size_fallback(path, header, size), None) as dec:
        if dec.version not in ("evt2", "evt3"):
            raise InputError(f"{path}: RAW version {dec.version} is not supported (EVT2, EVT3)")
        W, H = dec.dimensions
        parts = [pk["events"] for pk in dec if "events" in pk and len(pk["events"])]
    return _concat(parts), (int(H), int(W))


def _read_dat(path: Path, faery, size: tuple[int, int] | None = None):
    header, data_len = _prophesee_header(path)
    cam = camera_size(header)
    fallback = (cam[0], cam[1]) if cam is not None else size
    if data_len == 0:
        # faery writes no event-type bytes before the first event, and its
        # decoder cannot open such a header-only file: zero events
        if "Width" in header and "Height" in header:
            return None, (int(header["Height"]), int(header["Width"]))
        return None, None if fallback is None else (int(fallback[1]), int(fallback[0]))
    with faery.dat.Decoder(path, None, None) as dec:
        if dec.event_type != "cd":
            raise InputError(f"{path}: DAT event type '{dec.event_type}' is not CD (polarity) events")
        dims = dec.dimensions if dec.dimensions is not None else fallback
        shape = None if dims is None else (int(dims[1]), int(dims[0]))
        parts = [pk for pk in dec if len(pk)]
    return _concat(parts), shape


def _prophesee_header(path: Path) -> tuple[dict[str, str], int]:
    """The ``% key value`` lines at the start of a DAT/RAW file, and the number
    of bytes after them."""
    size = path.stat().st_size
    with open(path, "rb") as fh:
        head = fh.read(1 << 16)  # headers are a few hundred bytes
    header, n = {}, 0
    while head.startswith(b"%", n):
        end = head.find(b"\n", n)
        if end < 0:
            break
        key, _, value = head[n + 1:end].decode("latin-1").strip().partition(" ")
        header[key] = value.strip()
        n = end + 1
    return header, size - n
