"""``gs2e report``: one self-contained HTML report of a results tree."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    p = sub.add_parser(
        "report", help="write the HTML report of a results tree",
        description="One self-contained HTML file (images embedded): dataset overview, "
                    "held-out quality against training time, per-job wall/CPU time and memory, "
                    "event rate and inter-event-interval histograms (optionally against a real "
                    "recording), frame thumbnails and event previews. Missing inputs are "
                    "shown as 'missing'.")
    p.add_argument("--results-dir", default="results", help="the results folder (default: results)")
    p.add_argument("--out", default=None, help="HTML file (default: RESULTS_DIR/report.html; "
                   "written atomically)")
    p.add_argument("--real-events", default=None, metavar="PATH",
                   help="real recording (.aedat4/.raw/.dat/.h5/.npz) to compare with "
                        "(overrides metrics.real_events)")
    p.add_argument("--no-real-events", action="store_true",
                   help="no real comparison even if metrics.real_events is set")
    p.add_argument("--scenes", nargs="*", default=None, help="scene ids (default: all)")
    add_config_args(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging
    from pathlib import Path

    from gs2e.common.log import timed
    from gs2e.report.build import build_report, n_images, write_report
    from gs2e.report.settings import MetricsSettings

    log = logging.getLogger("gs2e.report")
    cfg = MetricsSettings.load(args.config_json, args.config)
    real = None if args.no_real_events else (args.real_events or cfg.real_events)
    out = Path(args.out) if args.out else Path(args.results_dir) / "report.html"
    timings: dict[str, float] = {}
    with timed("report", log, timings):
        text = build_report(args.results_dir, real, args.scenes, cfg, timings)
        write_report(out, text)
    log.info("wrote %s (%.1f kB, %d images) in %.2f s", out, len(text.encode()) / 1e3,
             n_images(text), timings["report"])
    return 0
