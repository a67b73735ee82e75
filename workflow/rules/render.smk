rule render:
    input:
        model=res("{scene}", "splat"),
        trajectories=res("{scene}", "trajectories"),
        # a scene below its model's quality gates is not rendered (gs2e.dataset); ancient:
        # its existence counts, not its time, so a gate rerun (a threshold or its code
        # edited) does not rerender what passed
        model_gate=ancient(res("{scene}", "model_gate.json")),
    output:
        directory(res("{scene}", "frames", "{traj}")),
    params:
        cfg=stage_cfg("render"),
        # the event sensor's camera (events.sensor), so frames and events share it
        sensor=render_sensor_arg,
        code=code_version("render"),
        trajectory=run_trajectory,
        # a run under a lighting condition: its light; the frame camera's noise seed
        light=light_arg,
        seed=render_seed_arg,
    conda:
        ENV
    log:
        res("{scene}", "logs", "render_{traj}.log"),
    benchmark:
        res("{scene}", "benchmarks", "render_{traj}.tsv")
    threads: workflow.cores
    resources:
        mem_mb=lambda wc, attempt: 3000 * attempt,
        runtime=lambda wc, attempt: 120 * attempt,
    shell:
        "{GS2E} render --model {input.model:q} --trajectory {params.trajectory:q}"
        " --out {output:q} --threads {threads} --scene-id {wildcards.scene} {params.sensor}"
        " {params.light} {params.seed}"
        " --config-json {params.cfg:q} 2> {log:q}"
