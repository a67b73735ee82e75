rule train:
    input:
        rules.sfm.output,
    output:
        directory(res("{scene}", "splat")),
    params:
        cfg=stage_cfg("splat"),
        seed=stage_seed("train"),
        code=code_version("train"),
        ckpt=res("{scene}", ".splat.ckpt"),
        target=train_target_arg,
    conda:
        ENV
    log:
        res("{scene}", "logs", "train.log"),
    benchmark:
        res("{scene}", "benchmarks", "train.tsv")
    threads: workflow.cores
    resources:
        mem_mb=lambda wc, attempt: 6000 * attempt,
        runtime=train_runtime_min,
    shell:
        "{GS2E} train --scene {input:q} --out {output:q} --seed {params.seed}"
        " --threads {threads} --scene-id {wildcards.scene} --checkpoint-dir {params.ckpt:q} {params.target}"
        " --config-json {params.cfg:q} 2> {log:q}"
