"""``gs2e gate`` (one scene's quality gates), ``gs2e dataset-status`` (what a run
of many scenes finished, and why the others failed) and ``gs2e datasheet``."""

from __future__ import annotations

import argparse


def register(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    p = sub.add_parser("gate", help="check a finished scene against the dataset's quality gates",
                       description="Measure a scene's registered views, held-out PSNR and events per "
                                   "pixel and compare them with the dataset section's thresholds. "
                                   "Passes: writes OUT (the values, the thresholds). Fails: one line "
                                   "with every failed gate, exit 2, nothing written (the scene's "
                                   "exports, which depend on OUT, are not made).")
    p.add_argument("--scene-dir", required=True, help="results/<scene>")
    p.add_argument("--scene-id", required=True)
    p.add_argument("--runs", nargs="*", default=[], help="the scene's runs (render.trajectories)")
    p.add_argument("--model-only", action="store_true",
                   help="only the gates of the trained model (registered views, held-out PSNR), "
                        "before anything is rendered from it")
    p.add_argument("--out", required=True, help="gate.json (written atomically)")
    add_config_args(p)
    p.set_defaults(func=run_gate)
    register_status(sub)


def run_gate(args: argparse.Namespace) -> int:
    import logging

    from gs2e.common.atomic import write_json_atomic
    from gs2e.common.errors import InputError
    from gs2e.dataset.gates import GATES, MODEL_GATES, failed_gates, measure
    from gs2e.dataset.settings import DatasetSettings

    cfg = DatasetSettings.load(args.config_json, args.config)
    values = measure(args.scene_dir, [] if args.model_only else args.runs)
    reasons = failed_gates(values, cfg, MODEL_GATES if args.model_only else tuple(GATES))
    if reasons:
        raise InputError(f"scene '{args.scene_id}' fails its quality gates: {'; '.join(reasons)}")
    write_json_atomic(args.out, {"scene_id": args.scene_id, "passed": True, "model_only": args.model_only,
                                 "values": values, "thresholds": cfg.as_dict()})
    logging.getLogger("gs2e.dataset").info("scene %s passes its quality gates", args.scene_id)
    return 0


def register_status(sub: argparse._SubParsersAction) -> None:
    from gs2e.cli import add_config_args

    p = sub.add_parser("dataset-status", help="which scenes of a run finished, and why the others failed",
                       description="For each scene: passed (every output the workflow plans for it "
                                   "exists, its gate.json among them) or failed, with the stage that "
                                   "failed and the one-line error of that job's log. Reads what "
                                   "`snakemake --summary scenes` prints; writes OUT (parquet, one row "
                                   "per scene) and prints the status line. `gs2e dataset` does all this "
                                   "itself.")
    p.add_argument("--results-dir", required=True, help="the run's results_dir")
    p.add_argument("--snakemake-summary", required=True, metavar="TSV",
                   help="the output of `snakemake --summary scenes` (- = standard input)")
    p.add_argument("--scenes", nargs="*", default=None,
                   help="scene ids (default: every folder of RESULTS_DIR the summary names)")
    p.add_argument("--out", required=True, help="scene_status.parquet (written atomically)")
    p.set_defaults(func=run_status)

    d = sub.add_parser("datasheet", help="write the dataset's datasheet (Gebru et al.)",
                       description="A datasheet in Markdown whose answers come from the run: the scenes, "
                                   "their sources and terms (read from the input folders), the gates, "
                                   "the statistics of summary.parquet and the scenes that failed.")
    d.add_argument("--summary", required=True, help="summary.parquet")
    d.add_argument("--status", default=None, help="scene_status.parquet of `gs2e dataset` (optional)")
    rows = d.add_mutually_exclusive_group(required=True)
    rows.add_argument("--scenes-table", help="the scenes table (layouts and input folders)")
    rows.add_argument("--scenes-json", help="its rows as JSON, [{scene_id, layout, path}, ...] (the workflow "
                                            "passes them as a parameter: a table moved elsewhere reruns nothing)")
    d.add_argument("--out", required=True, help="datasheet.md (written atomically)")
    add_config_args(d)
    d.set_defaults(func=run_datasheet)

    r = sub.add_parser("dataset", help="run the workflow over many scenes; report the scenes that failed",
                       description="Runs Snakemake over every scene with --keep-going (a scene that "
                                   "fails does not stop the others), records each scene's status "
                                   "(results/scene_status.parquet), then builds the summary, report and "
                                   "datasheet over all scenes, the failed ones with their reasons. "
                                   "Exit status 0: every scene passed; 3: the dataset was built and "
                                   "some scenes failed (the last line says how many and why); 1 or 2: "
                                   "the workflow itself failed (its message).")
    r.add_argument("--configfile", nargs="+", required=True, help="config files, merged in order")
    r.add_argument("--cores", default="all", help="Snakemake's --cores (default: all)")
    r.add_argument("snakemake_args", nargs=argparse.REMAINDER,
                   help="after --: more Snakemake arguments (a profile, --dry-run, ...)")
    r.set_defaults(func=run_dataset)


def run_status(args: argparse.Namespace) -> int:
    import sys

    from gs2e.dataset.status import read_snakemake_summary, scene_status, status_line, write_status

    text = sys.stdin.read() if args.snakemake_summary == "-" else open(args.snakemake_summary).read()
    table = scene_status(args.results_dir, read_snakemake_summary(text, args.results_dir, args.scenes))
    write_status(table, args.out)
    print(status_line(table))
    return 0


def run_datasheet(args: argparse.Namespace) -> int:
    import json

    from gs2e.common.errors import InputError
    from gs2e.dataset.card import write_datasheet
    from gs2e.dataset.settings import DatasetSettings

    if args.scenes_table is not None:
        from gs2e.config import load_scenes

        scenes = load_scenes(args.scenes_table)
    else:
        scenes = json.loads(args.scenes_json)
        if not (isinstance(scenes, list) and all(isinstance(r, dict) and {"scene_id", "layout"} <= set(r)
                                                  for r in scenes)):
            raise InputError("--scenes-json: expected a list of {scene_id, layout, path} objects")
    write_datasheet(args.summary, args.status, scenes,
                    DatasetSettings.load(args.config_json, args.config), args.out)
    return 0


def run_dataset(args: argparse.Namespace) -> int:
    from gs2e.dataset.run import run_dataset as run

    extra = [a for a in args.snakemake_args if a != "--"]
    return run(args.configfile, args.cores, extra)
