# gs2e workflow: sparse multi-view photos -> event-camera datasets.
# This file is the real entry point (rule `all` lives here, not in an include).
# Rules are thin: each calls the `gs2e` CLI; all logic lives in the gs2e package.

import os

# Defaults ship with the workflow; --configfile / --config given by the user
# are merged on top and the result is validated in common.smk.
configfile: os.path.join(workflow.basedir, "config", "config.yaml")

# `snakemake --report report.html` (or .zip): this description, the run's
# statistics and the outputs marked with report(...) in the rules.
report: "workflow/report/workflow.rst"


include: "workflow/rules/common.smk"


onstart:
    sweep_stale_temporaries()


rule all:
    input:
        all_targets(),
    default_target: True


# Every scene's own outputs (products, metrics, gate, exports, bench tables), without the
# dataset-wide tables: what `gs2e dataset` runs with --keep-going before it records which
# scenes failed and why (results/scene_status.parquet; docs/dataset.md).
rule scenes:
    input:
        [p for sid in SCENES for p in scene_outputs(sid)],


include: "workflow/rules/ingest.smk"
include: "workflow/rules/sfm.smk"
include: "workflow/rules/splat.smk"
include: "workflow/rules/trajectory.smk"
include: "workflow/rules/render.smk"
include: "workflow/rules/events.smk"
include: "workflow/rules/export.smk"
include: "workflow/rules/bench.smk"
include: "workflow/rules/metrics.smk"
include: "workflow/rules/dataset.smk"
