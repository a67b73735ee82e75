"""Benchmark: event-file readers and writers (faery, aedat, expelliarmus, dv-processing).

Measures, per container and library, read and write speed (M events/s), file
size (bytes per event) and correctness:

- reads of the real DVXplorer recording (../shared/data/events/dvxplorer_sample.aedat4,
  when present) against the ``aedat`` package (gs2e's AEDAT4 reader until now);
- reads of synthetic files (1280x720 sensor, absolute times from 1.7e15 us, 60 s,
  so EVT3's 24-bit clock wraps three times) against the events written;
- writes: the file read back by the same library, events and sensor size compared;
- EVT3 with one quiet gap of 1 s across a 2^24 us wrap (three events), the
  case a camera never produces but a simulator does.

DSEC HDF5 through gs2e (h5py, gzip) is measured as the baseline. A library that
is not installed is reported as such (``pip install -e .[bench]`` installs all).
Writes benchmarks/results/bench_event_io.csv and .png; the last line is the headline.

    python benchmarks/bench_event_io.py [--quick] [--n N]
"""

from __future__ import annotations

import importlib
import os
import tempfile
from pathlib import Path

import numpy as np

from harness import SHARED, best_s, parser, pyplot, report, save_plot, write_csv

REAL = SHARED / "events" / "dvxplorer_sample.aedat4"  # skipped if absent
W, H = 1280, 720
T0_US = 1_700_000_000_000_000
EV_DTYPE = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("on", "?")])
FIELDS = ("t", "x", "y", "p")


def synthetic(n: int, seed: int = 0) -> dict[str, np.ndarray]:
    """n events over 60 s on a 1280x720 sensor, corners included."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(T0_US, T0_US + 60_000_000, n)).astype(np.int64)
    x = rng.integers(0, W, n).astype(np.uint16)
    y = rng.integers(0, H, n).astype(np.uint16)
    x[-1], y[-1] = W - 1, H - 1
    return {"t": t, "x": x, "y": y, "p": rng.integers(0, 2, n).astype(np.uint8)}


def have(module: str) -> bool:
    try:
        importlib.import_module(module)
        return True
    except ImportError:
        return False


def best_of(fn, repeat: int):
    """(result of the last call, best wall time in s: :func:`harness.best_s`)."""
    last = [None]

    def call():
        last[0] = fn()

    best = best_s(call, repeat)
    return last[0], best


def compare(got: dict | None, want: dict) -> str:
    """'yes', or what differs."""
    if got is None:
        return "no: nothing read"
    if len(got["t"]) != len(want["t"]):
        return f"no: {len(got['t'])} events, want {len(want['t'])}"
    bad = [k for k in FIELDS if not np.array_equal(np.asarray(got[k]).astype(np.int64),
                                                   np.asarray(want[k]).astype(np.int64))]
    if not bad:
        return "yes"
    if bad == ["t"] and len(want["t"]):
        off = np.asarray(got["t"]).astype(np.int64) - np.asarray(want["t"]).astype(np.int64)
        if np.all(off == off[0]):
            return f"no: t shifted by {off[0]} us"
        return f"no: t wrong for {int(np.count_nonzero(off))} events"
    return "no: " + ",".join(bad)


def _fields(a: np.ndarray, p: str = "on") -> dict:
    return {"t": a["t"], "x": a["x"], "y": a["y"], "p": a[p]}


def _faery_array(ev: dict, dtype=EV_DTYPE, p: str = "on") -> np.ndarray:
    a = np.empty(len(ev["t"]), dtype)
    a["t"], a["x"], a["y"], a[p] = ev["t"], ev["x"], ev["y"], ev["p"]
    return a


# ---------------------------------------------------------------- readers
def read_faery(path: Path, kind: str):
    import faery

    if kind == "aedat4":
        with faery.aedat.Decoder(path) as d:
            dims = next(tr.dimensions for tr in d.tracks() if tr.data_type == "events")
            parts = [pk for tr, pk in d if tr.data_type == "events" and len(pk)]
        return _fields(np.concatenate(parts)), dims
    if kind == "dat":
        with faery.dat.Decoder(path, None, None) as d:
            dims = d.dimensions
            parts = [pk for pk in d if len(pk)]
        return _fields(np.concatenate(parts), "payload"), dims
    with faery.evt.Decoder(path, None, None) as d:
        dims = d.dimensions
        parts = [pk["events"] for pk in d if "events" in pk and len(pk["events"])]
    return _fields(np.concatenate(parts)), dims


def read_aedat(path: Path, kind: str):
    import aedat

    d = aedat.Decoder(str(path))
    streams = d.id_to_stream()
    sid = min(i for i, s in streams.items() if s["type"] == "events")
    parts = [p["events"] for p in d if p["stream_id"] == sid and "events" in p]
    return _fields(np.concatenate(parts)), (streams[sid]["width"], streams[sid]["height"])


def read_dv(path: Path, kind: str):
    import dv_processing as dv

    r = dv.io.MonoCameraRecording(str(path))
    dims = tuple(r.getEventResolution())
    parts = []
    while r.isRunning():
        e = r.getNextEventBatch()
        if e is None:
            break
        parts.append(e.numpy())
    a = np.concatenate(parts)
    return {"t": a["timestamp"], "x": a["x"], "y": a["y"], "p": a["polarity"]}, dims


def read_expelliarmus(path: Path, kind: str):
    from expelliarmus import Wizard

    a = Wizard(encoding=kind, fpath=str(path)).read()
    return _fields(a, "p"), None  # the API returns no sensor size


def read_h5(path: Path, kind: str):
    from gs2e.events.io import read_h5 as rd

    ev, attrs = rd(path)
    return {k: getattr(ev, k) for k in FIELDS}, (attrs["width"], attrs["height"])


READERS = {"faery": read_faery, "aedat": read_aedat, "dv-processing": read_dv,
           "expelliarmus": read_expelliarmus, "gs2e/h5py": read_h5}
MODULE = {"faery": "faery", "aedat": "aedat", "dv-processing": "dv_processing",
          "expelliarmus": "expelliarmus", "gs2e/h5py": "h5py"}


# ---------------------------------------------------------------- writers
def write_faery(path: Path, kind: str, ev: dict) -> None:
    from gs2e.events.containers import aedat4_description

    import faery

    if kind == "aedat4":
        a = _faery_array(ev)
        with faery.aedat.Encoder(path, aedat4_description(W, H), faery.aedat.LZ4_DEFAULT) as e:
            for i in range(0, len(a), 1 << 16):
                e.write(0, a[i:i + (1 << 16)])
    elif kind == "dat":
        dt = np.dtype([("t", "<u8"), ("x", "<u2"), ("y", "<u2"), ("payload", "u1")])
        with faery.dat.Encoder(path, "dat2", "cd", True, (W, H)) as e:
            e.write(_faery_array(ev, dt, "payload"))
    else:
        with faery.evt.Encoder(path, kind, True, (W, H), True) as e:
            e.write({"events": _faery_array(ev)})


def write_expelliarmus(path: Path, kind: str, ev: dict) -> None:
    from expelliarmus import Wizard

    dt = np.dtype({"names": ["t", "x", "y", "p"], "formats": ["<i8", "<i2", "<i2", "u1"],
                   "offsets": [0, 8, 10, 12], "itemsize": 16, "aligned": True})
    a = np.empty(len(ev["t"]), dt)
    for k in FIELDS:
        a[k] = ev[k]
    Wizard(encoding=kind).save(str(path), a)


def write_dv(path: Path, kind: str, ev: dict) -> None:
    import dv_processing as dv

    # no numpy constructor for an EventStore: one push_back per event
    store = dv.EventStore()
    for t, x, y, p in zip(ev["t"].tolist(), ev["x"].tolist(), ev["y"].tolist(), ev["p"].tolist()):
        store.push_back(t, x, y, bool(p))
    w = dv.io.MonoCameraWriter(str(path), dv.io.MonoCameraWriter.EventOnlyConfig("gs2e", (W, H)))
    w.writeEvents(store)
    del w  # flushes and closes the file


def write_h5(path: Path, kind: str, ev: dict) -> None:
    from gs2e.events.io import H5EventWriter
    from gs2e.events.models import Events

    with H5EventWriter(path, W, H, int(ev["t"][0]), "gzip") as w:
        w.append(Events(ev["t"], ev["x"], ev["y"], ev["p"]))


WRITERS = {"faery": write_faery, "expelliarmus": write_expelliarmus, "dv-processing": write_dv,
           "gs2e/h5py": write_h5}
SUFFIX = {"aedat4": ".aedat4", "evt2": ".raw", "evt3": ".raw", "dat": ".dat", "dsec-h5": ".h5"}
PLAN = {  # container -> (readers, writers)
    "aedat4": (["aedat", "faery", "dv-processing"], ["faery", "dv-processing"]),
    "evt2": (["faery", "expelliarmus"], ["faery", "expelliarmus"]),
    "evt3": (["faery", "expelliarmus"], ["faery", "expelliarmus"]),
    "dat": (["faery", "expelliarmus"], ["faery", "expelliarmus"]),
    "dsec-h5": (["gs2e/h5py"], ["gs2e/h5py"]),
}
DV_WRITE_MAX = 200_000  # the per-event Python loop: measured on fewer events


def row(container, data, library, op, n, secs, nbytes, identical, size, note=""):
    return {"container": container, "data": data, "library": library, "op": op, "n_events": n,
            "time_s": round(secs, 5) if secs is not None else None,
            "meps": round(n / secs * 1e-6, 2) if secs else None,
            "bytes_per_event": round(nbytes / n, 2) if nbytes and n else None,
            "identical": identical, "sensor_size": size, "note": note}


def _size(dims) -> str:
    return "-" if dims is None else f"{int(dims[0])}x{int(dims[1])}"


def run(n: int, repeat: int, tmp: Path, real: Path) -> list[dict]:
    rows = []
    ev = synthetic(n)
    if real.exists():
        # the reference: the aedat package, gs2e's AEDAT4 reader before faery
        ref = read_aedat(real, "aedat4")[0] if have("aedat") else None
        for lib in PLAN["aedat4"][0]:
            if not have(MODULE[lib]):
                rows.append(row("aedat4", "real", lib, "read", 0, None, None, "-", "-", "not installed"))
                continue
            (got, dims), s = best_of(lambda: READERS[lib](real, "aedat4"), max(repeat, 5))
            rows.append(row("aedat4", "real", lib, "read", len(got["t"]), s, real.stat().st_size,
                            compare(got, ref) if ref is not None else "-", _size(dims),
                            "reference" if lib == "aedat" else "vs aedat"))
    for container, (readers, writers) in PLAN.items():
        # the file every reader is measured on: written by the first writer
        files = {}
        for lib in writers:
            if not have(MODULE[lib]):
                rows.append(row(container, "synthetic", lib, "write", 0, None, None, "-", "-",
                                "not installed"))
                continue
            sub = {k: v[:DV_WRITE_MAX] for k, v in ev.items()} if lib == "dv-processing" else ev
            shift = 0
            if lib == "expelliarmus":  # its headers have no t0: given times from the first event
                shift = int(ev["t"][0])
                sub = {**ev, "t": ev["t"] - shift}
            path = tmp / f"{container}_{lib.replace('/', '_')}{SUFFIX[container]}"
            s = best_s(lambda: (path.unlink(missing_ok=True), WRITERS[lib](path, container, sub)), repeat)
            files[lib] = path
            back_lib = lib if lib in readers else readers[0]
            try:
                got, dims = READERS[back_lib](path, container)
                ok, size = compare({**got, "t": got["t"].astype(np.int64) + shift},
                                   {**sub, "t": sub["t"] + shift}), _size(dims)
            except Exception as exc:  # a reader refusing a writer's file is a result too
                ok, size = f"no: {type(exc).__name__}: {str(exc)[:60]}", "-"
            note = f"read back with {back_lib}"
            if lib == "dv-processing":
                note += f"; {len(sub['t'])} events (per-event push_back from Python)"
            if shift:
                note += "; times given from the first event (no t0 in its header)"
            rows.append(row(container, "synthetic", lib, "write", len(sub["t"]), s,
                            path.stat().st_size, ok, size, note))
        src = files.get(writers[0])
        if src is None:
            continue
        for lib in readers:
            if not have(MODULE[lib]):
                rows.append(row(container, "synthetic", lib, "read", 0, None, None, "-", "-",
                                "not installed"))
                continue
            try:
                (got, dims), s = best_of(lambda: READERS[lib](src, container), repeat)
                ok, size = compare(got, ev), _size(dims)
            except Exception as exc:
                (got, s, ok, size) = ({"t": []}, None, f"no: {type(exc).__name__}: {str(exc)[:60]}", "-")
            rows.append(row(container, "synthetic", lib, "read", len(got["t"]), s, src.stat().st_size,
                            ok, size, f"file written by {writers[0]}"))
    # EVT3 with one quiet second across the first 2^24 us wrap
    g = 1_000_000
    gap = {"t": np.array([T0_US, T0_US + (1 << 24) - g // 2, T0_US + (1 << 24) + g // 2], np.int64),
           "x": np.array([1, 2, 3], np.uint16), "y": np.array([4, 5, 6], np.uint16),
           "p": np.array([1, 0, 1], np.uint8)}
    for lib in ("faery", "expelliarmus"):
        if have(MODULE[lib]):
            path = tmp / f"gap_{lib}.raw"
            shift = T0_US if lib == "expelliarmus" else 0  # as above: no t0 in its header
            WRITERS[lib](path, "evt3", {**gap, "t": gap["t"] - shift})
            got, dims = READERS[lib](path, "evt3")
            ok = compare({**got, "t": got["t"].astype(np.int64) + shift}, gap)
            rows.append(row("evt3", "1 s gap across wrap", lib, "write+read", 3, None, None, ok,
                            _size(dims), f"written and read back with {lib}"))
    return rows


def main() -> None:
    ap = parser(__doc__, quick="1 M events, one repetition (~15 s)")
    ap.add_argument("--n", type=int, default=None, help="synthetic events (default 5 M, quick 1 M)")
    ap.add_argument("--real", type=Path, default=REAL, help="real AEDAT4 recording")
    args = ap.parse_args()
    n = args.n or (1_000_000 if args.quick else 5_000_000)
    repeat = 1 if args.quick else 3
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR")) as d:
        rows = run(n, repeat, Path(d), args.real)
    csv_path = write_csv("bench_event_io", rows)

    table = [f"{'container':>9} {'data':>19} {'library':>13} {'op':>10} {'events':>9} {'M ev/s':>7} "
             f"{'B/ev':>6} {'size':>9}  identical"]
    for r in rows:
        table.append(f"{r['container']:>9} {r['data']:>19} {r['library']:>13} {r['op']:>10} "
                     f"{r['n_events']:>9} {r['meps'] if r['meps'] is not None else '-':>7} "
                     f"{r['bytes_per_event'] if r['bytes_per_event'] is not None else '-':>6} "
                     f"{r['sensor_size']:>9}  {r['identical']}{'  (' + r['note'] + ')' if r['note'] else ''}")

    plt = pyplot()
    from matplotlib.ticker import FormatStrFormatter, NullFormatter

    timed = [r for r in rows if r["meps"] and r["op"] in ("read", "write") and r["data"] == "synthetic"]
    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharey=False)
    for ax, op in zip(axes, ("read", "write")):
        rs = [r for r in timed if r["op"] == op]
        labels = [f"{r['container']} / {r['library']}" for r in rs]
        colors = ["tab:green" if r["identical"] == "yes" else "tab:red" for r in rs]
        ax.barh(labels, [r["meps"] for r in rs], color=colors)
        ax.set_xscale("log")
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("M events / s (log)")
        ax.set_title(op)
        ax.invert_yaxis()
    fig.suptitle(f"{n / 1e6:g} M synthetic events, 1280x720; green = identical events back, "
                 "red = not (see the CSV's 'identical' column)")
    png = save_plot(fig, "bench_event_io", dpi=120)

    def get(container, lib, op, data="synthetic"):
        return next((r for r in rows if r["container"] == container and r["library"] == lib
                     and r["op"] == op and r["data"] == data), None)

    ok = [c for c in ("aedat4", "evt2", "evt3", "dat")
          if (get(c, "faery", "read") or {}).get("identical") == "yes"]
    okw = [c for c in ("aedat4", "evt2", "evt3", "dat")
           if (get(c, "faery", "write") or {}).get("identical") == "yes"]
    fr = [get(c, "faery", "read")["meps"] for c in ok]
    real_f, real_a = get("aedat4", "faery", "read", "real"), get("aedat4", "aedat", "read", "real")
    gap = next((r for r in rows if r["data"] == "1 s gap across wrap" and r["library"] == "faery"), {})
    real = (f"; DVXplorer recording: faery {real_f['identical']} vs aedat, {real_f['meps']} vs "
            f"{real_a['meps']} M ev/s" if real_f and real_a else "")
    report("\n".join(table),
           f"headline: faery reads {'/'.join(ok)} with identical events at {min(fr):g}-{max(fr):g} M ev/s "
           f"and writes {'/'.join(okw)} that read back identical{real}; "
           f"EVT3 with a quiet gap across a 2^24 us wrap: {gap.get('identical', '-')}", [csv_path, png])


if __name__ == "__main__":
    main()
