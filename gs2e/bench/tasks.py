"""The benchmark's tasks, registered in one place.

A task is a function from one trajectory's dataset to scored rows
(:class:`Task`); this module lists them, and everything that names a task
derives from it: ``gs2e bench --task`` choices, the workflow's ``{task}``
wildcard and its jobs' threads and run time, the checks of
:func:`gs2e.bench.dataset.load_dataset`, and the per-task columns of the
dataset table (:mod:`gs2e.bench.summary`). The schema's ``bench.tasks`` enum
is held equal to it by ``tests/test_bench.py``. Light on purpose (no
numerical imports): the Snakefile and the CLI's argument parser read it; a
task's module is imported when the task runs.

Adding a task: write ``run(ds, cfg, user) -> (rows, shown, example)`` (see
:class:`Task`), then ``register(Task("name", run))``; to run it from the
workflow, also add its name to the schema's ``bench.tasks`` enum.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from gs2e.common.errors import InputError
from gs2e.common.registry import PluginRegistry, add, resolve


@dataclass(frozen=True)
class Task:
    """One benchmark task.

    run : ``run(ds, cfg, user)`` or its import path ``"module:function"``:
        ds a :class:`gs2e.bench.dataset.Dataset`, cfg the resolved
        :class:`gs2e.bench.run.BenchConfig`, user the user's methods (name ->
        callable); returns (rows: one dict per method x frame with at least
        method, frame, t_us, t_rel_s, motion_px, n_events, psnr, ssim, mse,
        theta, time_s; shown: name -> image of the example frame, "sharp"
        included; example: that frame's index).
    needs_blur, needs_trajectory, needs_depth : what the dataset must hold
        (checked before any work, with an error naming the folder or flag).
    colour_events : reads events under a colour filter (``events.cfa``,
        ``color_davis346``); the other tasks read luminance events and refuse them.
    threads, runtime_min : the workflow job's threads and run time (minutes).
    summary : ``summary(group, row)`` or its import path: adds the task's own
        columns to a dataset-table row from the task's rows of one trajectory
        and method (a pandas DataFrame sorted by time); None: the common ones.
    """

    name: str
    run: Callable | str
    needs_blur: bool = False
    needs_trajectory: bool = False
    threads: int = 1
    runtime_min: int = 60
    summary: Callable | str | None = None
    needs_depth: bool = False
    colour_events: bool = False

    def runner(self) -> Callable:
        return resolve(self.run)

    def summariser(self) -> Callable | None:
        return None if self.summary is None else resolve(self.summary)


TASKS: dict[str, Task] = PluginRegistry("gs2e.bench_tasks")


def register(task: Task) -> Task:
    """Add ``task`` (its name: lower-case letters, digits, underscores) to the registry."""
    return add(TASKS, task.name, task, "bench task")


def get_task(name: str) -> Task:
    if name not in TASKS:
        raise InputError(f"unknown bench task '{name}' (choose from {', '.join(TASKS)})")
    return TASKS[name]


def task_names() -> tuple[str, ...]:
    return tuple(TASKS)


register(Task("deblur", "gs2e.bench.deblur_task:run", needs_blur=True))
register(Task("video", "gs2e.bench.video_task:run", summary="gs2e.bench.video_task:summary"))
# recon3d trains three 3DGS models (minutes each, multi-threaded rasterizer)
register(Task("recon3d", "gs2e.bench.recon3d:run", needs_trajectory=True, threads=2,
              runtime_min=120, summary="gs2e.bench.recon3d:summary", colour_events=True))
register(Task("flow", "gs2e.bench.flow_task:run", needs_depth=True, summary="gs2e.bench.flow_task:summary"))
TASKS.plugins(register, lambda t: t.name)
