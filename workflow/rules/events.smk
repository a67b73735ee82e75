rule events:
    input:
        model=res("{scene}", "splat"),
        trajectories=res("{scene}", "trajectories"),
        # a scene below its model's quality gates is not rendered (gs2e.dataset); ancient:
        # its existence counts, not its time, so a gate rerun (a threshold or its code
        # edited) does not rerender what passed
        model_gate=ancient(res("{scene}", "model_gate.json")),
        # a custom sensor's YAML: editing it reruns the scene's event jobs
        sensor=lambda wc: SCENE_CFG[wc.scene]["events"]["sensor_file"] or [],
    output:
        report(directory(res("{scene}", "events", "{traj}")), patterns=["{video}.mp4"],
               category="Event previews", subcategory="{scene}",
               caption="../report/event_preview.rst",
               labels={"scene": "{scene}", "trajectory": "{traj}"}),
    params:
        cfg=stage_cfg("events"),
        # what changes pixels, from the render section (not its frame rate or outputs)
        background=lambda wc: ",".join(map(repr, SCENE_CFG[wc.scene]["render"]["background"])),
        scale=lambda wc: SCENE_CFG[wc.scene]["render"]["scale"],
        backend=lambda wc: SCENE_CFG[wc.scene]["render"]["backend"],
        order_step_px=lambda wc: SCENE_CFG[wc.scene]["render"]["order_step_px"],
        seed=lambda wc: derive_seed(SCENE_CFG[wc.scene]["seed"], f"{wc.scene}/{wc.traj}", "events"),
        code=code_version("events"),
        trajectory=run_trajectory,
        light=light_arg,
    conda:
        ENV
    log:
        res("{scene}", "logs", "events_{traj}.log"),
    benchmark:
        res("{scene}", "benchmarks", "events_{traj}.tsv")
    threads: workflow.cores
    resources:
        # measured peak RSS ~0.5 GB + ~0.5 GB/megapixel, +0.4 GB on a cold numba cache
        # (benchmarks/bench_cost_model.py): ~2 GB at 1080p, x2 headroom
        mem_mb=lambda wc, attempt: 4000 * attempt,
        runtime=lambda wc, attempt: 240 * attempt,
    shell:
        "{GS2E} events --model {input.model:q} --trajectory {params.trajectory:q}"
        " -o {output:q} --seed {params.seed} --threads {threads}"
        " --background {params.background} --scale {params.scale} --backend {params.backend}"
        " --order-step-px {params.order_step_px} {params.light}"
        " --config-json {params.cfg:q} 2> {log:q}"
