"""``gs2e dataset``: the workflow over many scenes, a scene's failure recorded
instead of stopping the others.

1. The config files are loaded and validated (after the workflow's own
   ``config/config.yaml``, as Snakemake merges them), and the scenes table read;
   then ``snakemake -n`` plans the run. A bad key, row or plan: one line, exit
   2, nothing run.
2. ``snakemake --keep-going scenes``: every scene's own outputs (rule ``scenes``);
   a failed job stops only the jobs that need its outputs.
3. ``snakemake --summary scenes``: every output each scene should make, with its
   rule's log; :func:`gs2e.dataset.status.scene_status` gives each scene's
   status, written to ``<results_dir>/scene_status.parquet``.
4. ``snakemake``: the dataset's summary, report and datasheet over the scenes that
   passed, the failed ones as rows with their reasons (the workflow reads the
   status table: ``workflow/rules/common.smk``).
5. The last line of its standard output says how many scenes passed and why
   the others failed (the first ten); the exit status is 0 when all passed
   and 3 when some failed (:data:`EXIT_SCENES_FAILED`).

It runs in the current folder (where the Snakefile is, or ``-- --snakefile
PATH``); relative paths of the config (scenes table, results) are read from there.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import time
from pathlib import Path

from gs2e.common.errors import ConfigError, GS2EError

log = logging.getLogger("gs2e.dataset")

# Exit status of a dataset built with some scenes failed (0: all passed; 1 and 2
# are gs2e's own: a bug, bad input or config).
EXIT_SCENES_FAILED = 3
STATUS_FILE = "scene_status.parquet"


class WorkflowFailed(GS2EError):
    """The workflow itself failed (not one scene's job): planning, or the
    dataset-wide summary, report or datasheet."""


# Largest input file Snakemake compares by checksum before rerunning a job on a newer
# one (its default: 1 MB). A scene's capture files copied anew (re-staged, rsync
# without -t) then rerun nothing where their bytes are the ones ingested
# (gs2e.io.selection.source_files); COLMAP images.bin and event files pass 1 MB.
MAX_CHECKSUM_FILE_BYTES = 64 << 20


def _snakemake(configfiles: list[str], cores: str, extra: list[str], *args: str,
               capture: bool = False) -> subprocess.CompletedProcess:
    # --configfile (like --config) takes every word after it: targets first, config files last.
    size = ([] if any(a.startswith("--max-checksum-file-size") for a in extra)
            else ["--max-checksum-file-size", str(MAX_CHECKSUM_FILE_BYTES)])
    # a run killed outright (SIGKILL, a node lost) leaves its running jobs marked
    # incomplete, and Snakemake would refuse to plan until told to redo them
    redo = [] if "--rerun-incomplete" in extra or "--ri" in extra else ["--rerun-incomplete"]
    cmd = [sys.executable, "-m", "snakemake", "--cores", str(cores), *size, *redo, *args, *extra,
           "--configfile", *configfiles]
    log.info("running: %s", " ".join(cmd))
    return subprocess.run(cmd, text=True, stdout=subprocess.PIPE if capture else None,
                          stderr=subprocess.STDOUT if capture else None)


def _last_error(text: str) -> str:
    """Snakemake's error in a captured output: its last non-empty lines, joined."""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    return " ".join(lines[-3:])[:500] if lines else "no message"


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
    for a in extra:
        if a in ("-d", "--directory") or a.startswith("--directory="):
            raise ConfigError("run it in the workflow's folder (cd there) instead of "
                              "passing --directory to Snakemake")
    dry = any(a in ("-n", "--dry-run", "--dryrun") or (a.startswith("-") and not a.startswith("--")
                                                        and "n" in a[1:]) for a in extra)
    merged: dict = {}
    snakefile = next((extra[i + 1] for i, a in enumerate(extra[:-1]) if a in ("-s", "--snakefile")), "Snakefile")
    base = Path(snakefile).resolve().parent / "config" / "config.yaml"  # the Snakefile's configfile
    for f in ([str(base)] if base.is_file() else []) + list(configfiles):
        try:
            merged = deep_merge(merged, yaml.safe_load(Path(f).read_text()) or {})
        except OSError as exc:
            raise ConfigError(f"cannot read config file {f}: {exc.strerror}") from None
        except yaml.YAMLError as exc:
            raise ConfigError(f"config file {f} is not valid YAML: {exc}") from None
    cfg = load_config(merged)
    scenes = load_scenes(cfg["scenes"])
    for row in scenes:
        scene_config(cfg, row)
    ids = [r["scene_id"] for r in scenes]
    results = Path(cfg["results_dir"])
    log.info("dataset: %d scenes from %s into %s", len(ids), cfg["scenes"], results)
    t0 = time.monotonic()

    plan = _snakemake(configfiles, cores, [a for a in extra if a not in ("-n", "--dry-run", "--dryrun")],
                      "scenes", "--dry-run", "--quiet", "rules", capture=True)
    if plan.returncode:
        raise WorkflowFailed(f"snakemake cannot plan the run (exit {plan.returncode}): "
                             f"{_last_error(plan.stdout)}")
    if dry:
        print(plan.stdout, end="")
        return 0
    locks = Path(".snakemake", "locks")
    if locks.is_dir() and any(locks.iterdir()):
        # a dry run only warns; the run itself would stop at once (Snakemake's LockException)
        raise WorkflowFailed(
            f"the workflow folder is locked ({locks}): another Snakemake is running here, or one was "
            "killed and left its locks (and maybe jobs still running: stop them first); then "
            f"`snakemake --unlock --configfile {' '.join(configfiles)}` and run this again")
    run = _snakemake(configfiles, cores, extra, "--keep-going", "scenes")
    if run.returncode:
        log.warning("some jobs failed (snakemake exit %d); recording which scenes and why", run.returncode)
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
