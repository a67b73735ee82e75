rule sfm:
    input:
        rules.ingest.output,
    output:
        directory(res("{scene}", "sfm")),
    params:
        cfg=stage_cfg("sfm"),
        seed=stage_seed("sfm"),
        code=code_version("sfm"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "sfm.log"),
    benchmark:
        res("{scene}", "benchmarks", "sfm.tsv")
    threads: workflow.cores
    resources:
        mem_mb=lambda wc, attempt: 4000 * attempt,
        runtime=lambda wc, attempt: 60 * attempt,
    shell:
        "{GS2E} sfm --scene {input:q} --out {output:q} --seed {params.seed}"
        " --threads {threads} --scene-id {wildcards.scene}"
        " --config-json {params.cfg:q} 2> {log:q}"
