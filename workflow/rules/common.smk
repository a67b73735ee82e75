# Shared wiring: validated config, the scenes table, per-scene parameters.
import functools
import json
import os
import shlex
import sys
from pathlib import Path

from gs2e.bench.tasks import TASKS as BENCH_TASKS
from gs2e.codeversion import code_version
from gs2e.common.atomic import sweep_tree
from snakemake.logging import logger
from gs2e.config import (derive_seed, load_config, load_scenes, scene_config,
                         scene_params_json, section_json)
from gs2e.io.selection import source_files
from gs2e.light.settings import condition_json, run_names, split_run

# Reject invalid config / scenes table before any job runs.
config = load_config(config)
SCENES = {row["scene_id"]: row for row in load_scenes(config["scenes"])}


def scene_configs(config, scenes):
    """{scene id: its validated config}. A scene's config depends on its overrides
    only, so scenes with the same overrides share one (validated once, read-only):
    at the paper's scale thousands of scenes have one or two distinct overrides, and
    validating each took 80 ms (docs/scale.md, planning)."""
    by_overrides, out = {}, {}
    for sid, row in scenes.items():
        key = row.get("overrides", "")
        if key not in by_overrides:
            by_overrides[key] = scene_config(config, row)
        out[sid] = by_overrides[key]
    return out


SCENE_CFG = scene_configs(config, SCENES)
RESULTS = config["results_dir"]
ENV = "../../envs/gs2e.yaml"  # used with --sdm conda (relative to the rule files)

# Jobs run `python -m gs2e` from this checkout: the same code whether gs2e is
# pip-installed (venv) or not (a conda env built from envs/gs2e.yaml).
shell.prefix(f'export PYTHONPATH="{workflow.basedir}${{{{PYTHONPATH:+:$PYTHONPATH}}}}"; ')


def gs2e_python():
    """The interpreter jobs run: under --sdm conda the environment's `python`
    (Snakemake activates it), else the one running Snakemake -- the venv gs2e
    is installed in -- whatever the shell's PATH holds."""
    try:
        from snakemake.settings.types import DeploymentMethod

        if DeploymentMethod.CONDA in workflow.deployment_settings.deployment_method:
            return "python"
    except (ImportError, AttributeError):
        pass
    return shlex.quote(sys.executable)


# `exec`: the job's shell becomes gs2e, so the signals Snakemake or the
# scheduler sends (Ctrl-C, scancel) reach it and its cleanup runs.
GS2E = f"exec {gs2e_python()} -m gs2e"


def forward_interrupt_to_jobs():
    """On SIGINT to Snakemake (Ctrl-C, `kill -INT`), SIGTERM the local jobs at
    once: Snakemake's local executor would otherwise wait for them to finish.
    The jobs clean up and exit with gs2e's one-line message."""
    import signal

    previous = signal.getsignal(signal.SIGINT)

    def handler(signum, frame):
        from snakemake.shell import shell as snakemake_shell

        for proc in list(getattr(snakemake_shell, "_processes", {}).values()):
            try:
                proc.terminate()
            except (ProcessLookupError, OSError):
                pass
        if callable(previous):
            previous(signum, frame)
        else:
            raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: nothing to forward from here
        pass


forward_interrupt_to_jobs()


wildcard_constraints:
    scene="[A-Za-z0-9][A-Za-z0-9_.-]*",
    task="|".join(BENCH_TASKS),
    # a run: a trajectory, optionally under a lighting condition (<trajectory>@<condition>)
    traj="[A-Za-z0-9_.-]+(@[a-z0-9_]+)?",
    fmt="[a-z0-9]+",


def res(*parts):
    return str(Path(RESULTS, *parts))


def sweep_stale_temporaries():
    """Before the first job: remove the temporaries that jobs killed on this
    machine left under the results (`gs2e clean`); a rerun job also sweeps
    those of its own output, whichever host left them."""
    if Path(RESULTS).is_dir():
        removed, _, freed = sweep_tree(RESULTS)
        for t in removed:
            logger.info(f"removed stale temporary {t.path} (left by a killed job)")


# Keys that say which jobs exist, not what a job computes: left out of params
# so that listing one more trajectory does not rerun the others.
# (bench.real_video*: the dataset-level bench_real job's, not a scene's)
NOT_PARAMS = {"render": ("trajectories",), "export": ("formats", "trajectories"),
              "bench": ("tasks", "real_video", "real_video_theta", "sim2real", "sim2real_variants",
                        "sim2real_fit", "sim2real_fps", "sim2real_window_ms", "sim2real_warmup_ms",
                        "sim2real_aps_linear")}


def stage_cfg(section):
    """params: function giving one scene's config section as canonical JSON."""
    drop = NOT_PARAMS.get(section, ())
    return lambda wc: section_json(
        {section: {k: v for k, v in SCENE_CFG[wc.scene][section].items() if k not in drop}}, section)


def scene_params(sid):
    """The scene's whole config (without file locations) as canonical JSON.
    The export and bench sections are left out: exports are copies of the
    dataset in other layouts and the benchmark reads the dataset, so neither
    changes a scene metric or reruns a scene table."""
    return scene_params_json({k: v for k, v in SCENE_CFG[sid].items() if k not in ("export", "bench")})


def stage_seed(stage):
    return lambda wc: derive_seed(SCENE_CFG[wc.scene]["seed"], wc.scene, stage)


# Training time grows with the step budget: 20 min per 1000 steps covers ~1080p
# views on 8 cores (about 3-4 CPU-s per step per megapixel, benchmarks/
# bench_cost_model.py), so the paper's 30k steps get 10 h, not a fixed limit.
TRAIN_MIN_PER_1000_STEPS = 20


def train_runtime_min(wc, attempt):
    steps = SCENE_CFG[wc.scene]["splat"]["max_iterations"]
    return attempt * max(30, -(-steps * TRAIN_MIN_PER_1000_STEPS // 1000))


def sensor_size(sid):
    """The event sensor's pixel array 'WxH' of a scene (None: no sensor)."""
    ev = SCENE_CFG[sid]["events"]
    return None if ev["sensor"] is None else _sensor_size(section_json(SCENE_CFG[sid], "events"))


@functools.lru_cache(maxsize=None)
def _sensor_size(events_json):
    """'WxH' of an events section (as JSON): computed once per distinct section."""
    from gs2e.events.sensors import get_sensor
    from gs2e.events.settings import event_settings

    w, h = get_sensor(event_settings(json.loads(events_json))).size
    return f"{w}x{h}"


def train_target_arg(wc):
    """--target-size for splat.max_side=auto: the event sensor's array, the
    largest image a scene's outputs need ('' when there is no sensor, or
    max_side is set: then the sensor does not change the train job). Ingest
    and SfM never see the sensor: choosing one cannot change which views
    register."""
    size = sensor_size(wc.scene)
    if SCENE_CFG[wc.scene]["splat"]["max_side"] != "auto" or size is None:
        return ""
    return f"--target-size {size}"


def render_sensor_arg(wc):
    """Frames through the event sensor's camera, so frames and events share it."""
    size = sensor_size(wc.scene)
    if size is None:
        return ""
    return f"--sensor-size {size} --sensor-fit {SCENE_CFG[wc.scene]['events']['sensor_fit']}"


def scene_layout(wc):
    return SCENES[wc.scene]["layout"]


def scene_source(wc):
    """Inputs of ingest: the generated demo scene, or the files of the scene's
    folder (gs2e.io.selection.source_files: a copy with new mtimes and the same
    bytes reruns nothing)."""
    row = SCENES[wc.scene]
    if row["layout"] == "demo":
        return res(wc.scene, "source")
    files = source_files(row["path"])
    odd = next((f for f in files if "{" in f or "}" in f), None)
    if odd is not None:  # Snakemake reads braces in an input as a wildcard
        raise ValueError(f"scene '{wc.scene}': file {odd}: braces in a file name are not supported "
                         "(Snakemake takes them for a wildcard); rename it")
    return files


def scene_source_path(wc):
    """The folder (or file) ingest reads: --src."""
    row = SCENES[wc.scene]
    return res(wc.scene, "source") if row["layout"] == "demo" else row["path"]


def scene_runs(sid):
    """The runs of a scene: render.trajectories, and each plain trajectory
    again under every condition of light.runs (gs2e.light.settings.run_names)."""
    return run_names(SCENE_CFG[sid]["render"]["trajectories"], SCENE_CFG[sid]["light"]["runs"])


def run_trajectory(wc, input):
    """The trajectory file a run moves along (a run <trajectory>@<condition>: its trajectory's)."""
    return str(Path(input.trajectories, f"{split_run(wc.traj)[0]}.npz"))


def light_arg(wc):
    """--light-json of a lit run (its one condition, resolved: editing another
    condition reruns nothing); '' for a run at the trained radiance."""
    cond = split_run(wc.traj)[1]
    if cond is None:
        return ""
    return "--light-json " + shlex.quote(condition_json(SCENE_CFG[wc.scene]["light"], cond))


def render_seed_arg(wc):
    """--seed of the frame camera's noise (render.camera.model sensor only:
    the ideal camera draws nothing, and its jobs' params stay as they were)."""
    if SCENE_CFG[wc.scene]["render"]["camera"]["model"] != "sensor":
        return ""
    return f"--seed {derive_seed(SCENE_CFG[wc.scene]['seed'], f'{wc.scene}/{wc.traj}', 'render')}"


def scene_products(sid):
    """Every product of one scene: model, trajectories, frames, events and the
    aligned event windows."""
    out = [res(sid, "sfm"), res(sid, "splat"), res(sid, "trajectories")]
    for t in scene_runs(sid):
        out += [res(sid, "frames", t), res(sid, "events", t), res(sid, "windows", f"{t}.parquet")]
    return out


# Each scene's status from the last `gs2e dataset` (gs2e.dataset.run, which writes it):
# the scenes that failed are left out of the dataset-wide summary, report and datasheet,
# which list them with their reasons. A plain `snakemake` never writes it.
STATUS = res("scene_status.parquet")
FAILED = {}
if os.path.exists(STATUS):
    from gs2e.dataset.status import read_failed

    FAILED = read_failed(STATUS)
GOOD = [sid for sid in SCENES if sid not in FAILED]


def scene_exports(sid):
    """The exports export.formats asks for, one per format and exported
    trajectory (export.trajectories; null: every rendered one)."""
    x = SCENE_CFG[sid]["export"]
    return [res(sid, "export", f, t) for f in x["formats"]
            for t in (x["trajectories"] or scene_runs(sid))]


def scene_bench(sid):
    """The bench tables bench.tasks asks for, one per task and trajectory."""
    return [res(sid, "bench", task, f"{t}.parquet") for task in SCENE_CFG[sid]["bench"]["tasks"]
            for t in scene_runs(sid)]


# The dataset's bench table exists when any scene runs a benchmark task.
BENCH = any(scene_bench(sid) for sid in GOOD)


# Real recordings the video task's methods run on once (bench.real_video; load_config
# has checked that they exist).
REAL_VIDEO = list(config["bench"]["real_video"])


# Scenes with a real recording to compare with (bench.sim2real): their sim2real folders.
SIM2REAL = [res(sid, "sim2real") for sid in GOOD if SCENE_CFG[sid]["bench"]["sim2real"]]


def scene_outputs(sid):
    """Everything one scene makes: its products, metrics table, quality gate,
    exports and bench tables."""
    return (scene_products(sid) + [res(sid, "metrics.parquet"), res(sid, "gate.json")]
            + scene_exports(sid) + scene_bench(sid))


def all_targets():
    """The dataset summary (which needs every scene's metrics and products),
    the HTML report, the configured exports and, with bench.tasks, the bench
    table; with bench.real_video, the real recordings' table; with bench.sim2real,
    the scene's sim-to-real folder."""
    return ([res("summary.parquet"), res("report.html"), res("datasheet.md")]
            + [p for sid in GOOD for p in [res(sid, "gate.json")] + scene_exports(sid)]
            + ([res("bench.parquet")] if BENCH else []) + ([res("bench_real.parquet")] if REAL_VIDEO else [])
            + SIM2REAL)
