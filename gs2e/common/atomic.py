"""Atomic outputs: a stage either leaves its complete output or nothing.

Files and directories are written under a temporary name next to their final
path, flushed to disk (fsync) and renamed into place only when the writer
finished without error; on an exception (SIGTERM and Ctrl-C included, see
:func:`gs2e.cli.main`) the temporary is removed.

A job killed outright (SIGKILL: Slurm's memory and time limits, the OOM
killer) cannot clean up, so temporaries carry their owner in their name::

    .<name>.tmp-<pid>-<start>@<host>-<random>[<suffix>]

(``start``: the owner's start time in clock ticks since boot, 0 where
/proc is absent; ``suffix``: the final file's extension, for writers that go
by it). A temporary is *stale* when its owner is provably gone: same host and
no process with that pid and start time (a reused pid does not count as the
owner). Stale temporaries are removed

- when the same output is written again (any writer of ``path`` first sweeps
  ``path``'s temporaries; those of another host or of an unknown owner are
  removed too, because an output has one writer at a time: Snakemake never runs
  two jobs for one output, and a killed Slurm job is finished before its retry
  starts), and
- by :func:`sweep_tree` (``gs2e clean``, and the workflow's ``onstart``), which
  leaves other hosts' temporaries alone unless asked: their jobs may still run.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import re
import secrets
import shutil
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator

from gs2e.common.errors import InputError


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def default_file_mode() -> int:
    """Mode a plain open() would give a new file (0o666 minus the umask);
    mkstemp's temporaries are 0o600 and would keep that after the rename."""
    return 0o666 & ~_umask()


# ----------------------------------------------------------------- temporaries' owners
def _host() -> str:
    return re.sub(r"[^A-Za-z0-9.-]", "_", socket.gethostname()) or "localhost"


def _start_ticks(pid: int) -> int | None:
    """Start time of process ``pid`` (clock ticks since boot), 0 where /proc is
    absent, None if there is no such process (or it is a zombie)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return None if Path("/proc/self/stat").exists() else 0
    except OSError:
        return 0
    fields = stat[stat.rfind(")") + 2:].split()  # the command name may hold spaces
    if fields[0] in ("Z", "X"):  # killed, not yet reaped: it writes nothing more
        return None
    return int(fields[19])


def owner_tag() -> str:
    """``<pid>-<start>@<host>`` of this process (computed per call: forks differ)."""
    pid = os.getpid()
    return f"{pid}-{_start_ticks(pid) or 0}@{_host()}"


# rand: 8 characters from tempfile's alphabet (no '-'), so the host may hold '-'
_TEMP_RE = re.compile(r"^\.(?P<name>.+?)\.(?P<kind>tmp|old)-"
                      r"(?:(?P<pid>\d+)-(?P<start>\d+)@(?P<host>[A-Za-z0-9._-]+)-)?"
                      r"(?P<rand>[a-z0-9_]{8})(?P<suffix>\.[A-Za-z0-9]+)?$")


@dataclass(frozen=True)
class Temporary:
    """A temporary of an atomic writer found on disk."""

    path: Path
    final_name: str   # name of the output it belongs to
    owner: str | None  # "<pid>-<start>@<host>", None for untagged (older gs2e) names
    alive: bool | None  # False: owner gone; True: owner running; None: unknown (other host)


def parse_temporary(path: Path) -> Temporary | None:
    """The :class:`Temporary` a path names, or None if it is not one."""
    m = _TEMP_RE.match(path.name)
    if not m:
        return None
    final = m["name"]
    if m["pid"] is None:
        return Temporary(path, final, None, None)
    owner = f"{m['pid']}-{m['start']}@{m['host']}"
    if m["host"] != _host():
        return Temporary(path, final, owner, None)
    pid, start = int(m["pid"]), int(m["start"])
    now = _start_ticks(pid)
    alive = now is not None and (start == 0 or now == 0 or now == start)
    return Temporary(path, final, owner, alive)


def _remove(path: Path, measure: bool = False) -> int:
    """Remove a file or tree; returns the bytes freed if ``measure`` (else 0)."""
    size = 0
    try:
        if path.is_dir() and not path.is_symlink():
            if measure:
                for p in path.rglob("*"):
                    with contextlib.suppress(OSError):
                        size += p.lstat().st_size if p.is_file() else 0
            shutil.rmtree(path, ignore_errors=True)
        else:
            size = path.lstat().st_size
            path.unlink()
    except FileNotFoundError:
        return 0
    return size


def sweep_output(path: str | os.PathLike) -> list[Path]:
    """Remove the stale temporaries of the output ``path`` (see module doc:
    those of dead owners on this host, of other hosts and of unknown owners;
    never those of a live process here). Returns the removed paths."""
    final = Path(path)
    removed = []
    try:
        entries = list(os.scandir(final.parent))
    except OSError:
        return removed
    prefix = f".{final.name}."
    for e in entries:
        if not e.name.startswith(prefix):
            continue
        t = parse_temporary(Path(e.path))
        if t is not None and t.final_name == final.name and t.alive is not True:
            _remove(t.path)
            removed.append(t.path)
    return removed


def sweep_tree(root: str | os.PathLike, all_hosts: bool = False,
               dry_run: bool = False) -> tuple[list[Temporary], list[Temporary], int]:
    """Find the temporaries under ``root`` and remove the stale ones.

    Removes those whose owner is gone on this host; with ``all_hosts`` also
    those of other hosts and of unknown owners (use it only when no job writes
    under ``root``). Never descends into a temporary. Returns (removed, kept,
    bytes freed); with ``dry_run`` nothing is removed (``removed`` lists what
    would be).
    """
    removed: list[Temporary] = []
    kept: list[Temporary] = []
    freed = 0
    for dirpath, dirnames, filenames in os.walk(root):
        for name in [*dirnames, *filenames]:
            if not name.startswith("."):
                continue
            t = parse_temporary(Path(dirpath) / name)
            if t is None:
                continue
            if name in dirnames:
                dirnames.remove(name)  # never look inside a temporary
            if t.alive is False or (all_hosts and t.alive is None):
                removed.append(t)
                if not dry_run:
                    freed += _remove(t.path, measure=True)
            else:
                kept.append(t)
    return removed, kept, freed


# ----------------------------------------------------------------- checks before work
def check_writable(path: str | os.PathLike, what: str = "output") -> None:
    """Fail early (InputError naming ``path``) if ``path`` cannot be written:
    its nearest existing ancestor must be a folder where a file can be created
    (tried for real: permission bits say nothing for root or read-only mounts).
    Creates nothing that stays."""
    p = Path(path)
    anc = p.parent if p.name else p
    while not anc.exists():
        if anc.is_symlink():
            raise InputError(f"{what} {p}: {anc} is a broken symbolic link")
        anc = anc.parent
    if not anc.is_dir():
        raise InputError(f"{what} {p}: {anc} is not a folder")
    # named first, created and removed inside the try: SIGTERM raises at the next
    # bytecode, and must not land between creating the probe and removing it
    probe = _temp_name(anc / (p.name or "gs2e"))
    try:
        try:
            os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(probe)
    except OSError as exc:
        raise InputError(f"{what} {p}: cannot write in {anc} ({exc.strerror or exc})") from exc


# ----------------------------------------------------------------- durable writes
def _fsync_path(path: str | os.PathLike, directory: bool = False) -> None:
    fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    try:
        os.fsync(fd)
    except OSError as exc:  # some filesystems cannot fsync a directory
        if not (directory and exc.errno in (errno.EINVAL, errno.ENOTSUP, errno.EBADF)):
            raise
    finally:
        os.close(fd)


def _fsync_tree(root: Path) -> None:
    """Flush every file and folder under ``root`` (before it is renamed into
    place: a crash of the machine must not leave a complete-looking output of
    empty or half-written files)."""
    for dirpath, _, filenames in os.walk(root):
        for f in filenames:
            p = os.path.join(dirpath, f)
            if not os.path.islink(p):
                _fsync_path(p)
        _fsync_path(dirpath, directory=True)


def _commit(tmp: str | os.PathLike, final: Path) -> None:
    os.replace(tmp, final)
    _fsync_path(final.parent, directory=True)  # make the rename itself durable


def _temp_prefix(final: Path) -> str:
    return f".{final.name}.tmp-{owner_tag()}-"


def _temp_name(final: Path, suffix: str = "") -> Path:
    """A free temporary name beside ``final``, chosen before anything exists so
    the caller creates it inside its cleanup ``try``: a signal that lands just
    after creation (SIGTERM raises at the next bytecode) cannot leak it. The
    prefix holds this process's pid and start time, so no other process takes
    the name between this check and the creation."""
    while True:
        tmp = final.parent / f"{_temp_prefix(final)}{secrets.token_hex(4)}{suffix}"
        if not os.path.lexists(tmp):
            return tmp


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary directory that replaces ``path`` on success.

    On any exception the temporary directory is removed and ``path`` is left
    untouched (an existing ``path`` is replaced only on success). Stale
    temporaries of ``path`` (killed earlier writers) are removed first.
    """
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    sweep_output(final)
    tmp = _temp_name(final)
    try:
        os.mkdir(tmp, 0o777)  # minus the umask: outputs get normal permissions
        yield tmp
        _fsync_tree(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if final.exists() or final.is_symlink():
        old = final.with_name(f".{final.name}.old-{owner_tag()}-{secrets.token_hex(4)}")
        os.replace(final, old)
        _commit(tmp, final)
        _remove(old)
    else:
        _commit(tmp, final)


@contextlib.contextmanager
def scratch_dir(path: str | os.PathLike) -> Iterator[Path]:
    """A work folder beside the output ``path`` (named like its temporaries, so
    a killed job's is swept with them), removed on exit whatever happens."""
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_name(final)
    try:
        os.mkdir(tmp, 0o700)
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_file(path: str | os.PathLike, mode: str = "wb") -> Iterator[Any]:
    """Open a temporary file that is renamed to ``path`` when closed cleanly."""
    with atomic_path(path) as tmp, open(tmp, mode) as fh:
        yield fh


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary file path (for writers that take a filename, e.g. h5py,
    pyarrow; it keeps ``path``'s extension); it is renamed to ``path`` on
    success and removed on failure."""
    final = Path(path)
    final.parent.mkdir(parents=True, exist_ok=True)
    sweep_output(final)
    tmp_name = str(_temp_name(final, final.suffix))
    try:
        # 0o666 minus the umask: the renamed output gets normal permissions
        os.close(os.open(tmp_name, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
        yield Path(tmp_name)
        _fsync_path(tmp_name)
        _commit(tmp_name, final)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise


# ----------------------------------------------------------------- JSON
def json_safe(obj: Any) -> Any:
    """``obj`` with NaN/inf floats replaced by None (JSON null: "could not be
    computed"), numpy scalars and arrays as Python values, paths as strings."""
    import numpy as np

    if isinstance(obj, float) or isinstance(obj, np.floating):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, dict):
        return {k: json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return json_safe(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    return obj


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """Write ``data`` as indented JSON, atomically. numpy arrays become lists;
    NaN and inf become null (valid JSON that says "missing")."""
    text = json.dumps(json_safe(data), indent=2, sort_keys=False, allow_nan=False)
    with atomic_file(path, "w") as fh:
        fh.write(text + "\n")
