"""The ``gs2e`` command: one subcommand per pipeline stage.

Each stage package has a ``cli.py`` with ``register(subparsers)``; heavy imports
happen inside the subcommand's run function so ``gs2e --help`` stays fast.

One error path (:func:`main`): errors that are the user's or the machine's (bad
input, bad config, a file that cannot be read or written, a full disk, no
memory) print one line naming the file or key and exit with status 2; Ctrl-C
exits 130 and SIGTERM/SIGHUP 128 + the signal number, after cleaning up like an
exception; anything else is a bug in gs2e: one line, status 1. The traceback is
printed only with ``--debug`` (or ``GS2E_DEBUG=1``). Nothing partial is left
behind because all outputs are written atomically (gs2e.common.atomic), and
the output locations are checked for writability before any work starts.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import os
import signal
import sys
import threading
import time

from gs2e import __version__
from gs2e.common.errors import GS2EError, Terminated
from gs2e.common.log import process_usage, setup_logging

# Stage modules that provide subcommands, in pipeline order.
STAGE_CLIS = (
    "gs2e.demo.cli",
    "gs2e.io.cli",
    "gs2e.sfm.cli",
    "gs2e.splat.cli",
    "gs2e.trajectory.cli",
    "gs2e.render.cli",
    "gs2e.events.cli",
    "gs2e.export.cli",
    "gs2e.bench.cli",
    "gs2e.metrics.cli",
    "gs2e.dataset.cli",
    "gs2e.report.cli",
)


def add_config_args(p: argparse.ArgumentParser) -> None:
    """The two ways a subcommand receives its config section."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--config-json", metavar="JSON",
                   help="the stage's config section as JSON (what the workflow passes)")
    g.add_argument("--config", metavar="YAML",
                   help="a full gs2e config file; its section for this stage is used")


def size_arg(text: str) -> tuple[int, int]:
    """argparse type for a pixel array 'WxH' (e.g. 346x260)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH (e.g. 346x260), got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"expected a positive WxH, got {text!r}")
    from gs2e.common.camera import size_problem

    why = size_problem(w, h)
    if why:
        raise argparse.ArgumentTypeError(why)
    return w, h


def _register_config(sub) -> None:
    p = sub.add_parser("config", help="validate a config file or print the config reference",
                       description="Validate a config (and its scenes table) or print "
                                   "config/README.md generated from the schema.")
    p.add_argument("--doc", action="store_true", help="print the configuration reference (Markdown)")
    p.add_argument("--validate", metavar="YAML", help="validate this config file and its scenes table")
    p.add_argument("--print", dest="print_cfg", action="store_true",
                   help="with --validate: print the config with defaults filled in")
    p.set_defaults(func=_run_config)


def _run_config(args) -> int:
    import yaml

    from gs2e import config as C

    if args.doc:
        sys.stdout.write(C.schema_markdown())
    if args.validate:
        cfg = C.load_config(args.validate)
        scenes = C.load_scenes(cfg["scenes"])
        for row in scenes:
            C.scene_config(cfg, row)
        logging.getLogger("gs2e").info("%s is valid (%d scenes)", args.validate, len(scenes))
        if args.print_cfg:
            sys.stdout.write(yaml.safe_dump(cfg, sort_keys=False))
    return 0


def _register_clean(sub) -> None:
    p = sub.add_parser(
        "clean", help="remove temporaries left by killed jobs",
        description="Remove the temporaries (.<name>.tmp-*, .<name>.old-*) that jobs killed "
                    "outright (SIGKILL: Slurm memory/time limits, the OOM killer) left under "
                    "RESULTS_DIR. Only those whose owner process is gone are removed; those "
                    "of other hosts only with --all-hosts (their jobs may still be running). "
                    "Outputs and training checkpoints are never touched.")
    p.add_argument("results_dir", nargs="?", default="results", metavar="RESULTS_DIR",
                   help="folder to clean (default: results)")
    p.add_argument("-n", "--dry-run", action="store_true", help="list what would be removed")
    p.add_argument("--all-hosts", action="store_true",
                   help="also remove other hosts' and unattributed temporaries "
                        "(only when no job writes under RESULTS_DIR)")
    p.set_defaults(func=_run_clean)


def _run_clean(args) -> int:
    from pathlib import Path

    from gs2e.common.atomic import sweep_tree
    from gs2e.common.errors import InputError

    root = Path(args.results_dir)
    if not root.is_dir():
        raise InputError(f"{root}: no such folder")
    removed, kept, freed = sweep_tree(root, all_hosts=args.all_hosts, dry_run=args.dry_run)
    for t in removed:
        print(f"{'would remove' if args.dry_run else 'removed'} {t.path}")
    for t in kept:
        why = "its owner is running" if t.alive else "owner on another host (--all-hosts)"
        print(f"kept {t.path} ({why}: {t.owner or 'unknown'})")
    logging.getLogger("gs2e").info("%s: %d stale temporaries %s (%.1f MB), %d kept", root,
                                   len(removed), "found" if args.dry_run else "removed",
                                   freed / 1e6, len(kept))
    return 0


class _Parser(argparse.ArgumentParser):
    """argparse with the one-line error of every gs2e error (usage: --help)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="gs2e",
        description="Sparse multi-view photos -> event-camera datasets (GS2E pipeline).",
    )
    parser.add_argument("--version", action="version", version=f"gs2e {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    parser.add_argument("--debug", action="store_true",
                        help="print the traceback of an error (also GS2E_DEBUG=1)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _register_config(sub)
    _register_clean(sub)
    for mod_name in STAGE_CLIS:
        importlib.import_module(mod_name).register(sub)
    return parser


# Arguments that name outputs: checked for writability before any work starts.
OUTPUT_ARGS = ("out", "checkpoint_dir")


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def describe_os_error(exc: OSError, output: str | None = None) -> str:
    """'<file>: <reason>' for an OSError (both files for a failed rename); a
    full disk without a file name (HDF5, pyarrow) names ``output``."""
    full = exc.errno in DISK_FULL
    hint = " (the disk or the job's file-size limit is full: free space and rerun)" if full else ""
    if exc.filename is not None and exc.filename2 is not None:
        return f"{exc.filename} -> {exc.filename2}: {exc.strerror or exc}{hint}"
    if exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}{hint}"
    where = f"writing {output}: " if full and output else ""
    return f"{where}{_one_line(str(exc)) or type(exc).__name__}{hint}"


def _install_signal_handlers() -> None:
    """SIGTERM/SIGHUP raise :class:`Terminated` in the main thread (cleanup as
    for an exception); a second signal during that cleanup is ignored, Ctrl-C's
    SIGINT included (a terminal's Ctrl-C reaches the job's process group while
    the workflow forwards it as SIGTERM)."""
    if threading.current_thread() is not threading.main_thread():
        return
    # pycolmap's glog installs a C handler for SIGTERM on import (a stack dump,
    # then death, with no cleanup); imported first, it cannot replace ours
    try:
        import pycolmap  # noqa: F401
    except ImportError:
        pass

    def handler(signum, frame):
        for s in (signal.SIGTERM, signal.SIGHUP, signal.SIGINT):
            signal.signal(s, signal.SIG_IGN)
        raise Terminated(signum)

    for s in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, handler)


def main(argv: list[str] | None = None) -> int:
    """The ``gs2e`` program. With ``argv`` None (the console script, ``python -m
    gs2e``) the process ends right after the command (os._exit): every output
    is written, closed and renamed into place by then, and the interpreter's
    teardown only costs time (~0.5 CPU-s per job: freeing hundreds of MB and
    unloading torch and numba; after the usage line, so no job's CPU goes
    unreported) or crashes (after a failed write HDF5 crashes in it: exit 139
    instead of 2). In-process callers pass ``argv`` and get the exit status back."""
    rc = _main(argv)
    if argv is None:
        logging.shutdown()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    setup_logging(args.verbose)
    debug = args.debug or os.environ.get("GS2E_DEBUG", "") not in ("", "0")
    log = logging.getLogger("gs2e")
    t0 = time.perf_counter()
    log.info("gs2e %s %s", __version__, " ".join(sys.argv[1:] if argv is None else argv))
    if argv is None:  # the program only: an in-process caller keeps its own handlers
        _install_signal_handlers()
    if not debug and argv is None:  # the program only: in-process callers keep their hooks
        # after a failed write h5py reports the same error again from its
        # destructors (a traceback + "Exception ignored in ... __dealloc__"):
        # the one-line message below already says it
        # (Cython prints them through sys.excepthook, then sys.unraisablehook)
        sys.unraisablehook = lambda u: log.debug("ignored in %r: %s", u.object, u.exc_value)
        sys.excepthook = lambda typ, exc, tb: log.debug("ignored: %s: %s", typ.__name__, exc)

    def fail(kind: str, msg: str, rc: int) -> int:
        if debug:
            import traceback

            traceback.print_exc()
        print(f"gs2e {args.command}: {kind}: {_one_line(msg)}", file=sys.stderr)
        return rc

    try:
        from gs2e.common.atomic import check_writable

        for dest in OUTPUT_ARGS:
            if getattr(args, dest, None):
                check_writable(getattr(args, dest), f"output (--{dest.replace('_', '-')})")
        rc = args.func(args) or 0
    except GS2EError as exc:
        return fail("error", str(exc), 2)
    except OSError as exc:
        return fail("error", describe_os_error(exc, getattr(args, "out", None)), 2)
    except MemoryError:
        return fail("error", "out of memory (give the job more memory, or lower the "
                             "resolution / batch size)", 2)
    except KeyboardInterrupt:
        return fail("interrupted", "stopped by Ctrl-C; partial outputs removed", 130)
    except Terminated as exc:
        return fail("interrupted", f"{exc}; partial outputs removed", 128 + exc.signum)
    except Exception as exc:  # a bug in gs2e: still one line, traceback with --debug
        return fail("internal error", f"{type(exc).__name__}: {exc} "
                    "(please report it; rerun with --debug for the traceback)", 1)
    cpu_s, peak_mb = process_usage()
    # the line gs2e.report.io.read_job_usage reads (exact CPU and peak memory per job)
    log.info("gs2e %s finished in %.2f s (%.2f CPU-s, peak RSS %.1f MB)", args.command,
             time.perf_counter() - t0, cpu_s, peak_mb)
    return rc


if __name__ == "__main__":
    sys.exit(main())
