rule trajectory:
    input:
        rules.sfm.output,
    output:
        report(directory(res("{scene}", "trajectories")), patterns=["{plot}.png"],
               category="Trajectories", subcategory="{scene}",
               caption="../report/trajectories.rst", labels={"scene": "{scene}"}),
    params:
        cfg=stage_cfg("trajectory"),
        seed=stage_seed("trajectory"),
        code=code_version("trajectory"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "trajectory.log"),
    benchmark:
        res("{scene}", "benchmarks", "trajectory.tsv")
    threads: 1
    resources:
        mem_mb=lambda wc, attempt: 1000 * attempt,
        runtime=lambda wc, attempt: 10 * attempt,
    shell:
        "{GS2E} trajectory --scene {input:q} --out {output:q} --seed {params.seed}"
        " --config-json {params.cfg:q} 2> {log:q}"
