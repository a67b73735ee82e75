# A dataset of many scenes (gs2e.dataset, docs/dataset.md): each scene's quality gates
# and the datasheet (the target `gs2e dataset` runs with --keep-going, rule `scenes`,
# is in the Snakefile beside `all`).


# The datasheet (Gebru et al.): the scenes, their sources and terms read from the input
# folders, the gates, the statistics and the scenes that failed (gs2e.dataset.card).
def datasheet_inputs(wildcards):
    out = {"summary": res("summary.parquet")}
    if os.path.exists(STATUS):
        out["status"] = STATUS
    return out


# The gates a trained model can be judged by (registered views, held-out PSNR), before
# anything is rendered from it: a scene that fails them costs no render or event job.
rule model_gate:
    input:
        sfm=res("{scene}", "sfm"),
        splat=res("{scene}", "splat"),
    output:
        res("{scene}", "model_gate.json"),
    params:
        cfg=stage_cfg("dataset"),
        scene_dir=lambda wc: res(wc.scene),
        code=code_version("gate"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "model_gate.log"),
    benchmark:
        res("{scene}", "benchmarks", "model_gate.tsv")
    threads: 1
    shell:
        "{GS2E} gate --model-only --scene-dir {params.scene_dir:q} --scene-id {wildcards.scene}"
        " --out {output:q} --config-json {params.cfg:q} 2> {log:q}"


rule gate:
    input:
        sfm=res("{scene}", "sfm"),
        splat=res("{scene}", "splat"),
        events=lambda wc: [res(wc.scene, "events", t) for t in scene_runs(wc.scene)],
    output:
        res("{scene}", "gate.json"),
    params:
        cfg=stage_cfg("dataset"),
        runs=lambda wc: " ".join(scene_runs(wc.scene)),
        scene_dir=lambda wc: res(wc.scene),
        code=code_version("gate"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "gate.log"),
    benchmark:
        res("{scene}", "benchmarks", "gate.tsv")
    threads: 1
    shell:
        "{GS2E} gate --scene-dir {params.scene_dir:q} --scene-id {wildcards.scene} --runs {params.runs}"
        " --out {output:q} --config-json {params.cfg:q} 2> {log:q}"


rule datasheet:
    input:
        unpack(datasheet_inputs),
    output:
        res("datasheet.md"),
    params:
        cfg=section_json(config, "dataset"),
        # the table's rows, not its path: the same table elsewhere reruns nothing
        scenes=json.dumps([{k: row.get(k) for k in ("scene_id", "layout", "path")} for row in SCENES.values()]),
        status=lambda wc, input: f"--status {shlex.quote(input.status)}" if "status" in input.keys() else "",
        code=code_version("datasheet"),
    conda:
        ENV
    log:
        res("logs", "datasheet.log"),
    benchmark:
        res("benchmarks", "datasheet.tsv")
    threads: 1
    shell:
        "{GS2E} datasheet --summary {input.summary:q} {params.status} --scenes-json {params.scenes:q}"
        " --out {output:q} --config-json {params.cfg:q} 2> {log:q}"
