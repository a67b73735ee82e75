"""The ``gs2e`` command: one subcommand per pipeline stage.

Each stage package has a ``cli.py`` with ``register(subparsers)``; heavy imports
happen inside the subcommand's run function so ``gs2e --help`` stays fast.
Errors that are the user's (bad input, bad config) print one line naming the
file or key and exit with status 2; nothing partial is left behind because all
outputs are written atomically.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import time

from gs2e import __version__
from gs2e.common.errors import GS2EError
from gs2e.common.log import setup_logging

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
    "gs2e.metrics.cli",
    "gs2e.report.cli",
)


def add_config_args(p: argparse.ArgumentParser) -> None:
    """The two ways a subcommand receives its config section."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--config-json", metavar="JSON",
                   help="the stage's config section as JSON (what the workflow passes)")
    g.add_argument("--config", metavar="YAML",
                   help="a full gs2e config file; its section for this stage is used")


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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gs2e",
        description="Sparse multi-view photos -> event-camera datasets (GS2E pipeline).",
    )
    parser.add_argument("--version", action="version", version=f"gs2e {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    _register_config(sub)
    for mod_name in STAGE_CLIS:
        try:
            mod = importlib.import_module(mod_name)
        except ModuleNotFoundError as exc:
            if exc.name == mod_name:
                continue  # stage not implemented yet
            raise
        mod.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 1
    setup_logging(args.verbose)
    log = logging.getLogger("gs2e")
    t0 = time.perf_counter()
    log.info("gs2e %s %s", __version__, " ".join(sys.argv[1:] if argv is None else argv))
    try:
        rc = args.func(args) or 0
    except GS2EError as exc:
        log.error("%s", exc)
        print(f"gs2e {args.command}: error: {exc}", file=sys.stderr)
        return 2
    log.info("gs2e %s finished in %.2f s", args.command, time.perf_counter() - t0)
    return rc


if __name__ == "__main__":
    sys.exit(main())
