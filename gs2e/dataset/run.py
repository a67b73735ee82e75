"""``gs2e dataset``: the workflow over many scenes, a scene's failure recorded
instead of stopping the others.

1. The config files are loaded and validated, and the scenes table read, before
   any job runs (a bad key or row: one line, exit 2, nothing run).
2. ``snakemake --keep-going scenes``: every scene's own outputs (rule ``scenes``);
   a failed job stops only the jobs that need its outputs.
3. ``snakemake --summary scenes``: every output each scene should make, with its
   rule's log; :func:`gs2e.dataset.status.scene_status` gives each scene's
   status, written to ``<results_dir>/scene_status.parquet``.
4. ``snakemake``: the dataset's summary, report and datasheet over the scenes that
   passed, the failed ones as rows with their reasons (the workflow reads the
   status table: ``workflow/rules/dataset.smk``).
5. The last line says how many scenes passed and why the others failed;
   the exit status is 0 when all passed and 3 when some failed
   (:data:`EXIT_SCENES_FAILED`).
"""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from pathlib import Path

from gs2e.common.errors import GS2EError

log = logging.getLogger("gs2e.dataset")

# Exit status of a dataset built with some scenes failed (0: all passed; 1 and 2
# are gs2e's own: a bug, bad input or config).
EXIT_SCENES_FAILED = 3
STATUS_FILE = "scene_status.parquet"


class WorkflowFailed(GS2EError):
    """The workflow itself failed (not one scene's job): planning, or the
    dataset-wide summary, report or datasheet."""


def _snakemake(configfiles: list[str], cores: str, extra: list[str], *args: str,
               capture: bool = False) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(cores), "--configfile", *configfiles,
           *extra, *args]
    log.info("running: %s", " ".join(cmd))
    return subprocess.run(cmd, text=True, stdout=subprocess.PIPE if capture else None)


def run_dataset(configfiles: list[str], cores: str = "all", extra: list[str] | None = None) -> int:
    """Run the workflow over every scene of the merged config; returns the exit status.

    Parameters
    ----------
    configfiles : config files merged in order, as Snakemake's ``--configfile``
        (``config/config.yaml config/dataset.yaml`` for ``make dataset``).
    cores : Snakemake's ``--cores``.
    extra : more Snakemake arguments (a profile, ``--dry-run`` ...), given to
        every call.

    Raises
    ------
    ConfigError / InputError from validation (step 1); WorkflowFailed when
    Snakemake cannot plan the run or the dataset-wide jobs fail.
    """
    import yaml

    from gs2e.config import deep_merge, load_config, load_scenes, scene_config
    from gs2e.dataset.status import read_snakemake_summary, scene_status, status_line, write_status

    extra = list(extra or [])
    merged: dict = {}
    for f in configfiles:
        try:
            merged = deep_merge(merged, yaml.safe_load(Path(f).read_text()) or {})
        except OSError as exc:
            raise GS2EError(f"{f}: cannot be read ({exc.strerror})") from None
    cfg = load_config(merged)
    scenes = load_scenes(cfg["scenes"])
    for row in scenes:
        scene_config(cfg, row)
    ids = [r["scene_id"] for r in scenes]
    results = Path(cfg["results_dir"])
    log.info("dataset: %d scenes from %s into %s", len(ids), cfg["scenes"], results)
    t0 = time.monotonic()

    run = _snakemake(configfiles, cores, extra, "--keep-going", "scenes")
    if run.returncode:
        log.warning("some jobs failed (snakemake exit %d); recording which scenes and why", run.returncode)
    if "-n" in extra or "--dry-run" in extra:
        return 0
    summ = _snakemake(configfiles, cores, [a for a in extra if a != "--keep-going"], "--summary", "scenes",
                      capture=True)
    if summ.returncode:
        raise WorkflowFailed(f"snakemake --summary failed (exit {summ.returncode}): the workflow cannot be planned")
    table = scene_status(results, read_snakemake_summary(summ.stdout, results, ids))
    write_status(table, results / STATUS_FILE)
    final = _snakemake(configfiles, cores, extra)
    if final.returncode:
        raise WorkflowFailed(f"the dataset's summary, report or datasheet failed (snakemake exit "
                             f"{final.returncode}); see the logs under {results / 'logs'}")
    line = status_line(table)
    log.info("dataset finished in %.0f s; status of every scene: %s", time.monotonic() - t0,
             results / STATUS_FILE)
    print(line, flush=True)
    return EXIT_SCENES_FAILED if (table["status"] == "failed").any() else 0
