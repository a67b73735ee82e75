# Aligned event windows (always) and exports for event-based 3D methods
# (export.formats, off by default). See gs2e.export.


rule windows:
    input:
        frames=res("{scene}", "frames", "{traj}"),
        events=res("{scene}", "events", "{traj}"),
    output:
        res("{scene}", "windows", "{traj}.parquet"),
    params:
        code=code_version("windows"),
    conda:
        ENV
    log:
        res("{scene}", "logs", "windows_{traj}.log"),
    benchmark:
        res("{scene}", "benchmarks", "windows_{traj}.tsv")
    threads: 1
    resources:
        # reads every event of the trajectory once (13 bytes/event)
        mem_mb=lambda wc, attempt: 2000 * attempt,
        runtime=lambda wc, attempt: 30 * attempt,
    shell:
        "{GS2E} windows --frames {input.frames:q} --events {input.events:q}"
        " --out {output:q} 2> {log:q}"


rule export:
    input:
        frames=res("{scene}", "frames", "{traj}"),
        events=res("{scene}", "events", "{traj}"),
        windows=res("{scene}", "windows", "{traj}.parquet"),
        trajectories=res("{scene}", "trajectories"),
        sfm=res("{scene}", "sfm"),
        # a scene that fails its quality gates is not exported; ancient: a gate rerun does not
        # rewrite what was exported
        gate=ancient(res("{scene}", "gate.json")),
    output:
        directory(res("{scene}", "export", "{fmt}", "{traj}")),
    params:
        cfg=stage_cfg("export"),
        code=code_version("export"),
        # one per trajectory, not per format: the imu and rosbag exports carry the same IMU
        seed=lambda wc: derive_seed(SCENE_CFG[wc.scene]["seed"], f"{wc.scene}/{wc.traj}", "export"),
        scene_dir=lambda wc: res(wc.scene),
    conda:
        ENV
    log:
        res("{scene}", "logs", "export_{fmt}_{traj}.log"),
    benchmark:
        res("{scene}", "benchmarks", "export_{fmt}_{traj}.tsv")
    threads: 1
    resources:
        mem_mb=lambda wc, attempt: 3000 * attempt,
        runtime=lambda wc, attempt: 60 * attempt,
    shell:
        "{GS2E} export --scene-dir {params.scene_dir:q} --trajectory {wildcards.traj}"
        " --format {wildcards.fmt} --out {output:q} --scene-id {wildcards.scene}"
        " --seed {params.seed} --config-json {params.cfg:q} 2> {log:q}"
