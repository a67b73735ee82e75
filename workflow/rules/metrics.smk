# Real recording the report compares event statistics with (None: no comparison;
# load_config has checked that it exists).
REAL_EVENTS = config["metrics"]["real_events"]


def report_inputs(wildcards):
    """The summary, every scene's products and the real recording if configured."""
    out = {"summary": res("summary.parquet"),
           "products": [p for sid in GOOD for p in scene_products(sid)]}
    if REAL_EVENTS:
        out["real"] = REAL_EVENTS
    if BENCH:
        out["bench"] = res("bench.parquet")
    if REAL_VIDEO:
        out["bench_real"] = res("bench_real.parquet")
    if SIM2REAL:
        out["sim2real"] = SIM2REAL
    return out


rule scene_metrics:
    input:
        lambda wc: scene_products(wc.scene),
    output:
        res("{scene}", "metrics.parquet"),
    params:
        trajectories=lambda wc: " ".join(scene_runs(wc.scene)),
        config=lambda wc: scene_params(wc.scene),
        seeds=lambda wc: json.dumps({s: derive_seed(SCENE_CFG[wc.scene]["seed"], wc.scene, s)
                                     for s in ("sfm", "train", "trajectory")}),
        code=code_version("metrics"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "metrics.log"),
    benchmark:
        res("{scene}", "benchmarks", "metrics.tsv")
    threads: 1
    shell:
        "{GS2E} metrics --scene-dir {RESULTS}/{wildcards.scene} --scene-id {wildcards.scene}"
        " --trajectories {params.trajectories} --config-json {params.config:q}"
        " --seeds-json {params.seeds:q} --out {output:q} 2> {log:q}"


def summary_inputs(wildcards):
    """The metrics of the scenes that did not fail, and the status table when
    `gs2e dataset` wrote one (its failed scenes become rows with their reasons)."""
    out = {"tables": [res(sid, "metrics.parquet") for sid in GOOD]}
    if os.path.exists(STATUS):
        out["status"] = STATUS
    return out


rule summary:
    input:
        unpack(summary_inputs),
    output:
        res("summary.parquet"),
    params:
        status=lambda wc, input: f"--status {shlex.quote(input.status)}" if "status" in input.keys() else "",
        code=code_version("metrics"),
    conda:
        ENV
    log:
        res("logs", "summary.log"),
    benchmark:
        res("benchmarks", "summary.tsv")
    threads: 1
    shell:
        "{GS2E} summary {input.tables:q} {params.status} --out {output:q} 2> {log:q}"


rule report:
    input:
        unpack(report_inputs),
    output:
        report(res("report.html"), category="Dataset report",
               caption="../report/gs2e_report.rst"),
    params:
        cfg=section_json(config, "metrics"),  # carries real_events
        scenes=" ".join(GOOD),
        code=code_version("report"),
    conda:
        ENV
    log:
        res("logs", "report.log"),
    benchmark:
        res("benchmarks", "report.tsv")
    threads: 1
    resources:
        mem_mb=lambda wc, attempt: 2000 * attempt,
        runtime=lambda wc, attempt: 30 * attempt,
    shell:
        "{GS2E} report --results-dir {RESULTS:q} --out {output:q} --scenes {params.scenes}"
        " --config-json {params.cfg:q} 2> {log:q}"
