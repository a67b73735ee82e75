# The paper's downstream benchmark on the dataset's own ground truth (bench.tasks,
# off by default): one job per scene x trajectory x task, then one table for the
# dataset. See gs2e.bench.


rule bench:
    input:
        frames=res("{scene}", "frames", "{traj}"),
        events=res("{scene}", "events", "{traj}"),
        windows=res("{scene}", "windows", "{traj}.parquet"),
        trajectories=res("{scene}", "trajectories"),
    output:
        table=res("{scene}", "bench", "{task}", "{traj}.parquet"),
        png=report(res("{scene}", "bench", "{task}", "{traj}.png"), category="Benchmark",
                   subcategory="{scene}", caption="../report/bench.rst",
                   labels={"scene": "{scene}", "task": "{task}", "trajectory": "{traj}"}),
    params:
        cfg=stage_cfg("bench"),
        code=code_version("bench"),
        trajectory=run_trajectory,
        run=lambda wc: f"--run {wc.traj}" if split_run(wc.traj)[1] else "",
        seed=lambda wc: derive_seed(SCENE_CFG[wc.scene]["seed"], f"{wc.scene}/{wc.traj}", "bench"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "bench_{task}_{traj}.log"),
    benchmark:
        res("{scene}", "benchmarks", "bench_{task}_{traj}.tsv")
    # per task (gs2e.bench.tasks): recon3d trains three 3DGS models, multi-threaded
    threads: lambda wc: BENCH_TASKS[wc.task].threads
    resources:
        # every event of the trajectory in memory (19 bytes/event) + frames
        mem_mb=lambda wc, attempt: 3000 * attempt,
        runtime=lambda wc, attempt: BENCH_TASKS[wc.task].runtime_min * attempt,
    shell:
        "{GS2E} bench --task {wildcards.task} --frames {input.frames:q}"
        " --events {input.events:q} --windows {input.windows:q} --trajectory {params.trajectory:q}"
        " --out {output.table:q} --png {output.png:q} --scene-id {wildcards.scene} {params.run}"
        " --seed {params.seed} --threads {threads} --config-json {params.cfg:q} 2> {log:q}"


rule bench_summary:
    input:
        [t for sid in GOOD for t in scene_bench(sid)],
    output:
        res("bench.parquet"),
    params:
        code=code_version("bench_summary"),
    conda:
        ENV
    log:
        res("logs", "bench_summary.log"),
    benchmark:
        res("benchmarks", "bench_summary.tsv")
    threads: 1
    shell:
        "{GS2E} bench-summary {input:q} --out {output:q} 2> {log:q}"


rule bench_real:
    input:
        REAL_VIDEO,
    output:
        res("bench_real.parquet"),
    params:
        cfg=section_json({"bench": {k: config["bench"][k] for k in
                                    ("real_video_theta", "video_cf_alpha_rad_s", "video_learned")}}, "bench"),
        code=code_version("bench_real"),
    conda:
        ENV
    log:
        res("logs", "bench_real.log"),
    benchmark:
        res("benchmarks", "bench_real.tsv")
    threads: 1
    resources:
        mem_mb=lambda wc, attempt: 3000 * attempt,
        runtime=lambda wc, attempt: 30 * attempt,
    shell:
        "{GS2E} bench-real {input:q} --out {output:q} --config-json {params.cfg:q} 2> {log:q}"


# Simulated against real events on a real recording of the scene (bench.sim2real:
# an ECD sequence folder, the scene ingested with layout ecd): one job per scene.
rule sim2real:
    input:
        model=res("{scene}", "splat"),
        scene=res("{scene}", "sfm"),
        recording=lambda wc: SCENE_CFG[wc.scene]["bench"]["sim2real"],
    output:
        report(directory(res("{scene}", "sim2real")), patterns=["sim2real.png"], category="Sim-to-real",
               subcategory="{scene}", caption="../report/sim2real.rst", labels={"scene": "{scene}"}),
    params:
        cfg=lambda wc: section_json({"bench": {k: v for k, v in SCENE_CFG[wc.scene]["bench"].items()
                                               if k.startswith("sim2real_")}}, "bench"),
        events=stage_cfg("events"),
        seed=lambda wc: derive_seed(SCENE_CFG[wc.scene]["seed"], wc.scene, "sim2real"),
        code=code_version("sim2real"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "sim2real.log"),
    benchmark:
        res("{scene}", "benchmarks", "sim2real.tsv")
    threads: 1
    resources:
        mem_mb=lambda wc, attempt: 4000 * attempt,
        runtime=lambda wc, attempt: 60 * attempt,
    shell:
        "{GS2E} bench-sim2real --model {input.model:q} --scene {input.scene:q}"
        " --recording {input.recording:q} --out {output:q} --seed {params.seed}"
        " --events-json {params.events:q} --config-json {params.cfg:q} 2> {log:q}"
