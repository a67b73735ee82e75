"""The one harness of gs2e's benchmarks: common flags, timing, a baseline
revision's checkout, results (CSV + plot) and the report with its headline
printed last.

Every script is run as ``python benchmarks/bench_<name>.py [--quick] ...``;
Python puts the script's folder on the import path, so ``import harness``
needs no path edit, and ``gs2e`` is the installed (editable) package. Code a
baseline revision runs in a subprocess whose ``PYTHONPATH`` is that
revision's checkout (:func:`baseline_checkout`, :func:`gs2e_env`).

Conventions every script follows:

* ``--quick`` (from :func:`parser`): a run of about a minute, for ``make bench``;
* results go to ``benchmarks/results/<name>.csv`` and ``.png``
  (:func:`write_csv`, :func:`save_plot`);
* the report ends with one headline line (:func:`report`), naming the machine
  and its instruction set (:func:`machine`), since absolute times differ by
  machine and only ratios measured in the same run are compared.
"""

from __future__ import annotations

import argparse
import csv
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

BENCHMARKS = Path(__file__).resolve().parent
REPO = BENCHMARKS.parent
# GS2E_BENCH_RESULTS: elsewhere (the harness's own test writes to a temporary folder)
RESULTS = Path(os.environ.get("GS2E_BENCH_RESULTS") or BENCHMARKS / "results")
# ../shared/data beside the repo; one level further up for git worktrees (wt/<branch>). The
# same lookup as gs2e.testing.SHARED_DATA, kept here because the harness imports no gs2e:
# children that import it must load a baseline checkout's gs2e, which may predate gs2e.testing.
SHARED = next((p for p in (REPO.parent / "shared" / "data", REPO.parent.parent / "shared" / "data")
               if p.is_dir()), REPO.parent / "shared" / "data")
# Real scenes of ../shared/data as scenes-table rows: name -> (layout, input path).
SHARED_SCENES = {"temple_ring": ("folder", SHARED / "temple_ring"),
                 "llff_fern": ("folder", SHARED / "llff_fern" / "images"),
                 "mouse_colmap": ("colmap", SHARED / "mouse_colmap")}


# ---------------------------------------------------------------------- flags
def parser(doc: str | None, quick: str, baseline_rev: str | None = None) -> argparse.ArgumentParser:
    """The script's argument parser: its description is the first line of the
    module docstring ``doc``; ``--quick`` with the help ``quick`` (what the
    quick run does, and how long it takes); with ``baseline_rev``, a
    ``--baseline-rev`` flag defaulting to it (the revision measured against)."""
    ap = argparse.ArgumentParser(description=(doc or "").strip().splitlines()[0] if doc else None,
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=quick)
    if baseline_rev is not None:
        ap.add_argument("--baseline-rev", default=baseline_rev,
                        help="git revision whose code is the baseline, run in the same session")
    return ap


# --------------------------------------------------------------------- timing
@dataclass
class Timing:
    """Wall seconds, this process's CPU seconds and its finished children's
    CPU seconds over a :func:`clock` block (filled when the block ends)."""

    wall_s: float = float("nan")
    cpu_s: float = float("nan")
    child_cpu_s: float = float("nan")


def child_cpu_s() -> float:
    """CPU seconds (user + system) of this process's finished children."""
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


@contextmanager
def clock() -> Iterator[Timing]:
    """``with clock() as t: ...`` then ``t.wall_s``, ``t.cpu_s``, ``t.child_cpu_s``."""
    t = Timing()
    w0, c0, k0 = time.perf_counter(), time.process_time(), child_cpu_s()
    try:
        yield t
    finally:
        t.wall_s = time.perf_counter() - w0
        t.cpu_s = time.process_time() - c0
        t.child_cpu_s = child_cpu_s() - k0


@dataclass
class ChildRun:
    """One child process measured alone: wall seconds, its CPU seconds (user +
    system, all its threads and its own children), its peak RSS, its exit code
    and its output (stdout and stderr together)."""

    wall_s: float
    cpu_s: float
    peak_rss_mb: float
    returncode: int
    output: str


def run_child(cmd: list[str], env: dict | None = None, cwd: Path | str | None = None) -> ChildRun:
    """Run ``cmd`` and measure it by ``os.wait4`` (this child's own rusage:
    RUSAGE_CHILDREN would give the largest peak RSS of all children so far)."""
    with tempfile.TemporaryFile("w+") as out:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, text=True)
        _, status, ru = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        out.seek(0)
        text = out.read()
    return ChildRun(wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024.0,
                    os.waitstatus_to_exitcode(status), text)


def median_ms(fn: Callable[[], object], reps: int, clock: Callable[[], float] = time.perf_counter) -> float:
    """Median time of ``fn()`` in ms over ``reps`` calls by ``clock`` (wall
    time by default), after one untimed call (compiles, warms caches)."""
    fn()
    ts = []
    for _ in range(reps):
        t0 = clock()
        fn()
        ts.append(clock() - t0)
    ts.sort()
    return 1e3 * (ts[(len(ts) - 1) // 2] + ts[len(ts) // 2]) / 2


def median_cpu_ms(fn: Callable[[], object], reps: int) -> float:
    """:func:`median_ms` by CPU time (this process, all its threads): steadier
    than wall time on a shared machine, and what issue 44's targets count."""
    return median_ms(fn, reps, time.process_time)


def best_s(fn: Callable[[], object], reps: int) -> float:
    """Fastest wall time of ``fn()`` in seconds over ``reps`` calls (no warm-up:
    for work that does not compile, such as file I/O)."""
    best = float("inf")
    for _ in range(max(1, reps)):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def cpu_flags() -> set[str]:
    """This CPU's feature flags (/proc/cpuinfo; empty where there is none)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("flags") and ":" in line:
                return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


# Code generated for an instruction set, by target: the host's own choice, and
# AVX2 + FMA without AVX-512 (Haswell for numba, torch's AVX2 kernels).
ISA_TARGET_ENV = {"host": {}, "avx2": {"NUMBA_CPU_NAME": "haswell", "ATEN_CPU_CAPABILITY": "avx2"}}


def isa_targets(spec: str | None) -> list[str]:
    """Targets of :data:`ISA_TARGET_ENV` to measure: ``spec`` (comma-separated)
    if given, else host and avx2 where the host has AVX-512 (elsewhere host
    code is AVX2 code, or older)."""
    if spec:
        return spec.split(",")
    return ["host", "avx2"] if "avx512f" in cpu_flags() else ["host"]


def machine() -> str:
    """The CPU, the CPUs this process may use and the instruction set the
    kernels are compiled for, e.g. ``AMD EPYC 7B13, 2 CPUs, AVX2+FMA (no
    AVX-512)``, or ``..., AVX-512, kernels compiled for haswell (torch avx2)``
    under ``NUMBA_CPU_NAME`` / ``ATEN_CPU_CAPABILITY``: every figure names it."""
    model, flags = platform.processor() or platform.machine(), cpu_flags()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and ":" in line:
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    if "avx512f" in flags:
        isa = "AVX-512"
    elif "avx2" in flags:
        isa = "AVX2+FMA (no AVX-512)" if "fma" in flags else "AVX2 (no AVX-512)"
    else:
        isa = platform.machine()
    target = os.environ.get("NUMBA_CPU_NAME")  # code generated for another CPU than this one
    if target:
        isa += f", kernels compiled for {target}"
        if os.environ.get("ATEN_CPU_CAPABILITY"):
            isa += f" (torch {os.environ['ATEN_CPU_CAPABILITY']})"
    return f"{model}, {len(os.sched_getaffinity(0))} CPUs, {isa}"


# -------------------------------------------------------------- the baseline
@contextmanager
def baseline_checkout(rev: str) -> Iterator[Path]:
    """A detached git worktree of ``rev`` (removed afterwards): the baseline's
    code, to run with :func:`gs2e_env`."""
    with tempfile.TemporaryDirectory(prefix="gs2e_baseline_") as tmp:
        checkout = Path(tmp) / "checkout"
        subprocess.run(["git", "worktree", "add", "--detach", str(checkout), rev], cwd=REPO,
                       check=True, capture_output=True)
        try:
            yield checkout
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(checkout)], cwd=REPO,
                           capture_output=True)


def baseline_source(rev: str, path: str) -> str:
    """The text of ``path`` (relative to the repository) at revision ``rev``."""
    return subprocess.run(["git", "show", f"{rev}:{path}"], cwd=REPO, check=True,
                          capture_output=True, text=True).stdout


def gs2e_env(root: Path | str, **extra: str) -> dict:
    """Environment of a subprocess that imports the gs2e of checkout ``root``
    (``PYTHONPATH`` comes before the installed package), without progress bars."""
    path = os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {**os.environ, "PYTHONPATH": path, "GS2E_PROGRESS": "0", **extra}


def check_gs2e_root(root: Path | str) -> None:
    """Stop unless the imported gs2e is the one of checkout ``root`` (in a
    subprocess started with :func:`gs2e_env`)."""
    import gs2e

    if not Path(gs2e.__file__).resolve().is_relative_to(Path(root).resolve()):
        raise SystemExit(f"imported {gs2e.__file__}, not the gs2e of {root}")


def train_step_function():
    """``gs2e.splat.train.train_step`` of the gs2e imported (one optimiser step
    on one view), or, for a baseline from before the step was a function of
    its own, its training loop's body: render, loss, backward, Adam."""
    try:
        from gs2e.splat.train import train_step
        return train_step
    except ImportError:
        from gs2e.splat.loss import photometric_loss
        from gs2e.splat.model import render
        from gs2e.splat.strategy import PARAMS

        def train_step(p, opt, cam, gt, bg, sh_degree, backend, compute_dtype, lambda_ssim):
            for k in PARAMS:
                p[k].requires_grad_(True)
            photometric_loss(render(p, cam, bg, sh_degree, backend, compute_dtype)[0], gt,
                             lambda_ssim).backward()
            grads = {k: p[k].grad for k in PARAMS}
            for k in PARAMS:
                p[k].requires_grad_(False)
                p[k].grad = None
            opt.step(p, grads)

        return train_step


def cost_model_step_inputs(scene_dir: Path | str, n_views: int = 16):
    """What one training step of a cost-model run's scene takes, at the size and
    dtype its training ran at (``splat/train_stats.json``): (params, sh_degree,
    cameras, targets, (W, H), dtype). The cameras are ``n_views`` poses along its
    ``base_medium`` path; the targets the model's own renders there, dimmed
    (x 0.9 + 0.05) so that the loss has a gradient."""
    import json

    import numpy as np
    import torch

    from gs2e.splat.model import load_model, render
    from gs2e.splat.rasterize import SplatCamera
    from gs2e.trajectory import load_trajectory

    d = Path(scene_dir)
    stats = json.loads((d / "splat" / "train_stats.json").read_text())
    W, H, dtype = int(stats["train_width"]), int(stats["train_height"]), stats["compute_dtype"]
    traj = load_trajectory(d / "trajectories" / "base_medium.npz")
    params, info = load_model(d / "splat")
    K = np.asarray(traj.K, np.float64).copy()
    K[:2] *= W / float(traj.width)
    poses = traj.pose_at(np.asarray(traj.t_us[:: max(1, len(traj.t_us) // n_views)], np.float64))
    cams = [SplatCamera.from_c2w(c2w, K[0, 0], K[1, 1], K[0, 2], K[1, 2], W, H) for c2w in poses]
    sh = int(info["sh_degree"])
    with torch.no_grad():
        targets = [(render(params, c, torch.zeros(3), sh, "cpu")[0] * 0.9 + 0.05).contiguous() for c in cams]
    return params, sh, cams, targets, (W, H), dtype


# ------------------------------------------------------------------- results
def write_csv(name: str, rows) -> Path:
    """Write ``rows`` (dicts, or a DataFrame) to benchmarks/results/<name>.csv;
    returns the path. Rows may have different fields: the columns are every
    field in the order first seen, empty where a row lacks one."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.csv"
    if hasattr(rows, "to_csv"):
        rows.to_csv(path, index=False)
        return path
    rows = list(rows)
    fields = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=fields, restval="")
        wr.writeheader()
        wr.writerows(rows)
    return path


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_plot(fig, name: str, dpi: int = 120) -> Path:
    """Save ``fig`` as benchmarks/results/<name>.png (tight layout) and close it."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    pyplot().close(fig)
    return path


def plot_against_baseline(name: str, labels: list[str], baseline: list[float], today: list[float],
                          ylabel: str, title: str) -> Path:
    """Bars of the baseline (grey) and today (blue) side by side per label, as
    benchmarks/results/<name>.png; returns the path."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    x = list(range(len(labels)))
    ax.bar([i - 0.2 for i in x], baseline, 0.4, color="tab:gray", label="baseline")
    ax.bar([i + 0.2 for i in x], today, 0.4, color="tab:blue", label="today")
    ax.set_xticks(x, labels)
    ax.set(ylabel=ylabel, title=title)
    ax.legend()
    return save_plot(fig, name)


def report(table, headline: str, files: list[Path] | tuple = ()) -> None:
    """Print ``table`` (text or a DataFrame), the files written, then the
    headline as the last line, with the machine it was measured on."""
    if table is not None:
        print(table.to_string(index=False) if hasattr(table, "to_string") else str(table))
    for f in files:
        print(f"wrote {Path(f).relative_to(REPO) if Path(f).is_relative_to(REPO) else f}")
    sys.stdout.flush()
    print(f"{headline} [{machine()}]", flush=True)
