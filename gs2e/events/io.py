"""Event file I/O: DSEC-layout HDF5 (streaming, atomic), text, npz; AEDAT4 and
Prophesee RAW/DAT live in :mod:`gs2e.events.containers`, and :func:`read_events`
reads all of them.

DSEC layout (what :class:`H5EventWriter` writes)::

    /events/x   uint16  pixel column (0 = left)
    /events/y   uint16  pixel row (0 = top)
    /events/t   int64   microseconds relative to /t_offset, sorted
    /events/p   uint8   polarity: 1 = ON (brightness increase), 0 = OFF
    /ms_to_idx  uint64  ms_to_idx[i] = index of the first event with t >= 1000 i
                        (i = 0 .. ceil(t_last / 1000)), as in DSEC
    /t_offset   int64   absolute time (us) of t = 0 (the first frame's time)
    /theta/on, /theta/off  float32 (H, W) per-pixel contrast thresholds
    root attributes: format, polarity convention, width, height, model,
        parameters (JSON), seed, theta summaries, gs2e version

Datasets are chunked and compressed (gzip by default, readable everywhere;
``blosc`` needs hdf5plugin to read). The file is written under a temporary
name and renamed on success, so a failed run leaves nothing.

Text format (ESIM/rpg): one event per line ``t x y p`` with t in microseconds
(absolute), p in {0, 1} (or {-1, +1} with ``polarity="pm1"``).
npz: arrays t (int64 us, absolute), x, y (uint16), p (uint8 0/1), width, height.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path

import numpy as np

from gs2e.common.atomic import atomic_file, atomic_path
from gs2e.common.errors import InputError
from gs2e.events.models import Events

POLARITY_DOC = "p: 1 = ON (brightness increase), 0 = OFF (brightness decrease)"
_CHUNK = 1 << 16


def h5_compression(name: str) -> dict:
    """h5py dataset keywords of a compression name (gzip, lzf, blosc, none)."""
    if name == "gzip":
        return {"compression": "gzip", "compression_opts": 4, "shuffle": True}
    if name == "lzf":
        return {"compression": "lzf", "shuffle": True}
    if name == "blosc":
        import hdf5plugin
        # zstd level 3 on bit-shuffled chunks: on 10.5 M events 22.8 MB in 0.17 s, against
        # gzip-4's 23.5 MB in 1.18 s and zstd-5 byte-shuffled 23.4 MB in 0.94 s
        return dict(hdf5plugin.Blosc(cname="zstd", clevel=3, shuffle=hdf5plugin.Blosc.BITSHUFFLE))
    if name == "none":
        return {}
    raise ValueError(f"unknown compression '{name}'")


class H5EventWriter:
    """Streaming writer of a DSEC-layout HDF5 file (use as a context manager).

    ``append(events)`` takes time-sorted :class:`Events` batches (absolute us);
    the file appears at ``path`` only when the context exits without error.
    """

    def __init__(self, path: str | os.PathLike, width: int, height: int, t_offset_us: int,
                 compression: str = "gzip", attrs: dict | None = None):
        self.path = Path(path)
        self.width, self.height = int(width), int(height)
        self.t_offset = int(t_offset_us)
        self.comp = h5_compression(compression)
        self.compression = compression
        self.attrs = dict(attrs or {})
        self.n = 0
        self.t_last = None
        self._ms_idx: list[np.ndarray] = [np.zeros(1, np.uint64)]  # ms 0 starts at 0
        self._next_ms = 1  # next millisecond boundary to resolve
        self._stack = contextlib.ExitStack()

    def __enter__(self):
        import h5py
        self._tmp = self._stack.enter_context(atomic_path(self.path))
        self.f = self._stack.enter_context(h5py.File(self._tmp, "w"))
        g = self.f.create_group("events")
        self.ds = {}
        for name, dt in (("x", np.uint16), ("y", np.uint16), ("t", np.int64), ("p", np.uint8)):
            self.ds[name] = g.create_dataset(name, shape=(0,), maxshape=(None,), dtype=dt,
                                             chunks=(_CHUNK,), **self.comp)
        return self

    def append(self, ev: Events) -> None:
        n = len(ev)
        if n == 0:
            return
        t = ev.t.astype(np.int64) - self.t_offset
        if t[0] < 0 or (self.t_last is not None and t[0] < self.t_last):
            raise ValueError("events must be appended in time order, after t_offset")
        for name, arr in (("x", ev.x), ("y", ev.y), ("t", t), ("p", ev.p)):
            d = self.ds[name]
            d.resize((self.n + n,))
            d[self.n:] = arr
        # ms_to_idx: first index with t >= 1000 * ms, for the ms boundaries
        # that this batch reaches
        last_ms = int(t[-1] // 1000)
        if last_ms >= self._next_ms:
            bounds = np.arange(self._next_ms, last_ms + 1, dtype=np.int64) * 1000
            self._ms_idx.append((np.searchsorted(t, bounds, side="left") + self.n).astype(np.uint64))
            self._next_ms = last_ms + 1
        self.n += n
        self.t_last = int(t[-1])

    def __exit__(self, exc_type, exc, tb):
        try:
            if exc_type is None:
                # close the last millisecond: index n for the boundary after t_last
                self._ms_idx.append(np.array([self.n], np.uint64))
                self.f.create_dataset("ms_to_idx", data=np.concatenate(self._ms_idx), **self.comp)
                self.f.create_dataset("t_offset", data=np.int64(self.t_offset))
                self.f.attrs["format"] = "DSEC-style events (gs2e)"
                self.f.attrs["polarity"] = POLARITY_DOC
                self.f.attrs["t_unit"] = "microseconds, relative to t_offset"
                self.f.attrs["width"] = self.width
                self.f.attrs["height"] = self.height
                self.f.attrs["compression"] = self.compression
                for k, v in self.attrs.items():
                    if isinstance(v, np.ndarray):
                        grp, _, name = k.rpartition("/")
                        self.f.create_dataset(k, data=v, **self.comp)
                    elif isinstance(v, (dict, list, tuple)):
                        self.f.attrs[k] = json.dumps(v, sort_keys=True, default=_jsonable)
                    else:
                        self.f.attrs[k] = v
        finally:
            return self._stack.__exit__(exc_type, exc, tb)


def _jsonable(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def read_h5(path: str | os.PathLike, t_range_us: tuple[int, int] | None = None) -> tuple[Events, dict]:
    """Read a DSEC-layout file; returns (Events with absolute t in us, attrs).

    ``t_range_us`` = (start, end) absolute microseconds selects a window via
    ms_to_idx without reading the whole file.
    """
    with contextlib.closing(H5EventSlicer(path)) as s:
        f, t_off = s.file, s.t_offset_us
        i0, i1 = 0, s.n_events
        try:
            if t_range_us is not None and "ms_to_idx" in f:
                ms = f["ms_to_idx"]
                a = max(0, (int(t_range_us[0]) - t_off) // 1000)
                b = max(0, -(-(int(t_range_us[1]) - t_off) // 1000))
                i0 = int(ms[min(a, ms.shape[0] - 1)])
                i1 = int(ms[min(b, ms.shape[0] - 1)]) if b < ms.shape[0] else i1
            ev = s.read(i0, i1)
            attrs = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in f.attrs.items()}
            attrs["t_offset"] = t_off
            for k in ("theta/on", "theta/off"):
                if k in f:
                    attrs[k] = f[k][()]
        except (OSError, KeyError) as exc:
            raise InputError(f"{s.path}: not a readable DSEC-layout event file ({exc})") from exc
    if t_range_us is not None:
        keep = (ev.t >= t_range_us[0]) & (ev.t < t_range_us[1])
        ev = Events(ev.t[keep], ev.x[keep], ev.y[keep], ev.p[keep])
    return ev, attrs


class H5EventSlicer:
    """``events[i0:i1]`` of a DSEC-layout file through one open handle (``file``),
    for readers that take many index ranges (data loaders, with the ranges of a
    windows table): no search, no attribute reads per call.

    Open it in the process that reads (an HDF5 handle must not cross a fork).
    ``n_events`` is the file's event count; t comes back absolute (us, int64).
    """

    def __init__(self, path: str | os.PathLike):
        import h5py
        import hdf5plugin  # noqa: F401  (registers blosc & co. for reading)

        self.path = Path(path)
        try:
            self.file = h5py.File(self.path, "r")
        except OSError as exc:
            raise InputError(f"{self.path}: not a readable DSEC-layout event file ({exc})") from exc
        try:
            self.t_offset_us = int(self.file["t_offset"][()]) if "t_offset" in self.file else 0
            g = self.file["events"]
            self._t, self._x, self._y, self._p = g["t"], g["x"], g["y"], g["p"]
            self.n_events = int(self._t.shape[0])
            lengths = {k: int(d.shape[0]) for k, d in (("t", self._t), ("x", self._x), ("y", self._y),
                                                        ("p", self._p))}
            a = self.file.attrs
            # (width, height) the file declares (gs2e's files; DSEC's own carry none)
            self.size = ((int(a["width"]), int(a["height"])) if a.get("width") and a.get("height")
                         else (None, None))
        except (OSError, KeyError) as exc:
            self.file.close()
            raise InputError(f"{self.path}: not a readable DSEC-layout event file ({exc})") from exc
        if len(set(lengths.values())) > 1:
            self.file.close()
            raise InputError(f"{self.path}: events/t, x, y, p differ in length ({lengths}): a truncated "
                             "or padded file")

    def read(self, i0: int, i1: int) -> Events:
        """Events i0..i1-1, each field checked (:mod:`gs2e.export.conventions`:
        polarity in any convention, coordinates on the sensor the file's
        width/height attributes declare)."""
        from gs2e.export.conventions import coordinates_from_file, polarity_from_file

        if not 0 <= i0 <= i1 <= self.n_events:
            raise InputError(f"{self.path}: events[{i0}:{i1}] out of range ({self.n_events} events)")
        try:
            t, x, y, p = self._t[i0:i1], self._x[i0:i1], self._y[i0:i1], self._p[i0:i1]
        except OSError as exc:
            raise InputError(f"{self.path}: cannot read events[{i0}:{i1}] ({exc})") from exc
        if not np.issubdtype(t.dtype, np.integer):
            raise InputError(f"{self.path}: events/t must be integer microseconds, got {t.dtype}")
        where = str(self.path)
        return Events(t.astype(np.int64) + self.t_offset_us,
                      coordinates_from_file(x, self.size[0], "x", where),
                      coordinates_from_file(y, self.size[1], "y", where), polarity_from_file(p, where))

    def close(self) -> None:
        self.file.close()


# ---------------------------------------------------------------- text & npz
def write_text(path: str | os.PathLike, ev: Events, polarity: str = "01") -> None:
    """``t x y p`` per line (t absolute us); polarity "01" or "pm1" (-1/+1)."""
    p = ev.p.astype(np.int64)
    if polarity == "pm1":
        p = 2 * p - 1
    elif polarity != "01":
        raise ValueError(f"polarity must be '01' or 'pm1', got {polarity!r}")
    arr = np.stack([ev.t.astype(np.int64), ev.x.astype(np.int64), ev.y.astype(np.int64), p], 1)
    with atomic_file(path, "w") as fh:
        np.savetxt(fh, arr, fmt="%d", delimiter=" ")


class TextEventWriter:
    """Streaming text writer (context manager), same format as :func:`write_text`."""

    def __init__(self, path, polarity: str = "01"):
        self.path, self.polarity = path, polarity
        self._cm = atomic_file(path, "w")

    def __enter__(self):
        self.fh = self._cm.__enter__()
        return self

    def append(self, ev: Events) -> None:
        if len(ev) == 0:
            return
        p = ev.p.astype(np.int64)
        if self.polarity == "pm1":
            p = 2 * p - 1
        arr = np.stack([ev.t.astype(np.int64), ev.x.astype(np.int64), ev.y.astype(np.int64), p], 1)
        np.savetxt(self.fh, arr, fmt="%d", delimiter=" ")

    def __exit__(self, *exc):
        return self._cm.__exit__(*exc)


def read_text(path: str | os.PathLike) -> Events:
    """Read ``t x y p`` lines (t integer microseconds); polarity 0/1 or -1/+1
    (1, +1 = ON). Comment lines (#) skipped. InputError naming the file for
    a value that cannot be right (:mod:`gs2e.export.conventions`)."""
    from gs2e.export.conventions import coordinates_from_file, polarity_from_file

    path = Path(path)
    try:
        arr = np.loadtxt(path, dtype=np.int64, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a 't x y p' event text file ({exc})") from exc
    if arr.size == 0:
        return Events.empty()
    if arr.shape[1] != 4:
        raise InputError(f"{path}: expected 4 columns 't x y p', got {arr.shape[1]}")
    return Events(arr[:, 0], coordinates_from_file(arr[:, 1], None, "x", str(path)),
                  coordinates_from_file(arr[:, 2], None, "y", str(path)),
                  polarity_from_file(arr[:, 3], str(path)))


def write_npz(path: str | os.PathLike, ev: Events, width: int, height: int) -> None:
    with atomic_file(path, "wb") as fh:
        np.savez_compressed(fh, t=ev.t.astype(np.int64), x=ev.x, y=ev.y, p=ev.p,
                            width=np.int64(width), height=np.int64(height))


def read_npz(path: str | os.PathLike) -> tuple[Events, tuple[int, int]]:
    """Returns (events, (height, width))."""
    from gs2e.export.conventions import coordinates_from_file, polarity_from_file

    import zipfile

    path = Path(path)
    try:
        with np.load(path) as z:
            t, x, y, p = z["t"], z["x"], z["y"], z["p"]
            H, W = int(z["height"]), int(z["width"])
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise InputError(f"{path}: not a gs2e event npz ({exc})") from exc
    if not len(t) == len(x) == len(y) == len(p):
        raise InputError(f"{path}: t, x, y, p differ in length: a truncated or padded file")
    where = str(path)
    return Events(t.astype(np.int64), coordinates_from_file(x, W, "x", where),
                  coordinates_from_file(y, H, "y", where), polarity_from_file(p, where)), (H, W)


def read_events(path: str | os.PathLike,
                size: tuple[int, int] | None = None) -> tuple[Events, tuple[int, int] | None]:
    """Any supported event file, by suffix. ``size`` = (width, height) is the
    fallback for files whose header gives no size and names no known camera
    (:func:`gs2e.events.containers.read_container`); a header's own size wins.

    ``.aedat4`` (iniVation), ``.raw`` (Prophesee EVT2/EVT3, version from the
    header), ``.dat`` (Prophesee DAT) through :mod:`gs2e.events.containers`
    (faery); ``.h5``/``.hdf5`` (DSEC layout), ``.npz`` (gs2e), anything else as
    ``t x y p`` text.

    Every field is checked where it enters (:mod:`gs2e.export.conventions`):
    a polarity of any convention (0/1, -1/+1, bool) is read as such, a value
    that cannot be right (a polarity of 2, a negative coordinate, an event off
    the sensor the header or ``size`` declares) is a one-line InputError
    naming the file, the field and how many.

    Returns
    -------
    events : Events
        t absolute int64 us, x/y uint16, p uint8 (1 = ON).
    shape : (height, width) or None
        The sensor size from the file's header; None where the format does not
        say (text; a DSEC file without width/height attributes).
    """
    from gs2e.events.containers import READ_SUFFIXES, read_container

    path = Path(path)
    suf = path.suffix.lower()
    if not path.exists():
        raise InputError(f"{path}: no such event file")
    fallback = None if size is None else (int(size[1]), int(size[0]))
    if suf in READ_SUFFIXES:
        return _on_sensor(*read_container(path, size), path)
    if suf in (".h5", ".hdf5"):
        ev, attrs = read_h5(path)
        if attrs.get("width") and attrs.get("height"):
            return ev, (int(attrs["height"]), int(attrs["width"]))
        return _on_sensor(ev, fallback, path)  # DSEC's own files carry no sensor size
    if suf == ".npz":
        return read_npz(path)
    return _on_sensor(read_text(path), fallback, path)


def _on_sensor(ev: Events, shape: tuple[int, int] | None, path: Path) -> tuple[Events, tuple[int, int] | None]:
    """(ev, shape) after checking that every event lies on the (height, width)
    sensor, when one is known (from the header or the user)."""
    from gs2e.export.conventions import coordinates_from_file

    if shape is not None and len(ev):
        coordinates_from_file(ev.x, shape[1], "x", str(path))
        coordinates_from_file(ev.y, shape[0], "y", str(path))
    return ev, shape
