rule scene_metrics:
    input:
        lambda wc: scene_products(wc.scene),
    output:
        res("{scene}", "metrics.parquet"),
    params:
        trajectories=lambda wc: " ".join(SCENE_CFG[wc.scene]["render"]["trajectories"]),
        config=lambda wc: json.dumps(SCENE_CFG[wc.scene], sort_keys=True),
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
        "python -m gs2e metrics --scene-dir {RESULTS}/{wildcards.scene} --scene-id {wildcards.scene}"
        " --trajectories {params.trajectories} --config-json {params.config:q}"
        " --seeds-json {params.seeds:q} --out {output:q} 2> {log:q}"


rule summary:
    input:
        [res(sid, "metrics.parquet") for sid in SCENES],
    output:
        res("summary.parquet"),
    params:
        code=code_version("metrics"),
    conda:
        ENV
    log:
        res("logs", "summary.log"),
    benchmark:
        res("benchmarks", "summary.tsv")
    threads: 1
    shell:
        "python -m gs2e summary {input:q} --out {output:q} 2> {log:q}"
