rule demo_scene:
    output:
        directory(res("{scene}", "source")),
    params:
        cfg=stage_cfg("demo"),
        code=code_version("demo"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "demo_scene.log"),
    benchmark:
        res("{scene}", "benchmarks", "demo_scene.tsv")
    threads: 1
    shell:
        "{GS2E} demo-scene --out {output} --config-json {params.cfg:q} 2> {log:q}"


rule ingest:
    input:
        scene_source,
    output:
        directory(res("{scene}", "ingest")),
    params:
        src=scene_source_path,
        layout=scene_layout,
        cfg=stage_cfg("ingest"),
        code=code_version("ingest"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "ingest.log"),
    benchmark:
        res("{scene}", "benchmarks", "ingest.tsv")
    threads: 1
    shell:
        "{GS2E} ingest --layout {params.layout} --src {params.src:q} --out {output:q}"
        " --config-json {params.cfg:q} 2> {log:q}"
