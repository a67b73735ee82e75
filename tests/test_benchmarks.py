"""The benchmarks' harness and its rules: every script in benchmarks/ uses
benchmarks/harness.py (its flags, the report with the headline last), edits
no import path, imports no other script; a toy benchmark written as
docs/development.md says runs, with a baseline revision's checkout."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import pytest

from tests.conftest import REPO

BENCH = REPO / "benchmarks"
SCRIPTS = sorted(BENCH.glob("bench_*.py"))
SHARED_MODULES = {p.stem for p in BENCH.glob("*.py")} - {p.stem for p in SCRIPTS}


def _imports(tree: ast.AST) -> list[tuple[str, list[str]]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.append((node.module, [a.name for a in node.names]))
    return out


def test_there_are_benchmarks_and_shared_modules_are_public():
    assert len(SCRIPTS) >= 20
    assert "harness" in SHARED_MODULES
    assert not [m for m in SHARED_MODULES if m.startswith("_")], "shared modules have public names"


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_script_follows_the_harness_rules(script):
    src = script.read_text()
    tree = ast.parse(src)
    assert "sys.path" not in src, f"{script.name} edits the import path"
    imports = _imports(tree)
    mods = {m for m, _ in imports}
    assert "harness" in mods, f"{script.name} does not use benchmarks/harness.py"
    bad = sorted(m for m in mods if m.startswith("bench_") or m.split(".")[0] == "tests"
                 or (m.startswith("_") and m != "__future__"))
    assert not bad, f"{script.name} imports other scripts or private modules: {bad}"
    private = sorted(f"{m}.{n}" for m, names in imports if m in SHARED_MODULES | {"harness"}
                     for n in names if n.startswith("_"))
    assert not private, f"{script.name} imports private names: {private}"
    called = {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}
    called |= {n.func.attr for n in ast.walk(tree) if isinstance(n, ast.Call)
               and isinstance(n.func, ast.Attribute)}
    assert {"parser", "report"} <= called, f"{script.name}: flags from parser(), end with report()"


def test_every_script_answers_help():
    """--help imports each script's module level: the harness and the shared
    modules resolve without any path edit (the script's folder is on the path)."""
    env = {**os.environ, "GS2E_PROGRESS": "0"}
    env.pop("PYTHONPATH", None)

    def run(p):
        return p, subprocess.run([sys.executable, str(p), "--help"], capture_output=True, text=True,
                                 env=env, cwd="/", timeout=300)

    with ThreadPoolExecutor(2) as ex:
        for p, proc in ex.map(run, SCRIPTS):
            assert proc.returncode == 0, f"{p.name} --help: {proc.stderr[-2000:]}"
            assert "--quick" in proc.stdout, f"{p.name}: no --quick flag"


TOY = '''"""Benchmark: a toy (sum of squares, a loop against numpy).

    python bench_toy.py [--quick]
"""
import subprocess
import sys

import numpy as np

from harness import (baseline_checkout, check_gs2e_root, clock, gs2e_env, parser, pyplot,
                     report, save_plot, write_csv)


def main():
    ap = parser(__doc__, quick="a short array", baseline_rev="HEAD")
    ap.add_argument("--child", help=argparse_suppress)
    args = ap.parse_args()
    if args.child:
        check_gs2e_root(args.child)
        print("checkout", args.child)
        return
    n = 1000 if args.quick else 100000
    x = np.arange(n, dtype=np.float64)
    with clock() as base:
        a = sum(float(v) * float(v) for v in x)
    with clock() as new:
        b = float(x @ x)
    assert a == b
    with baseline_checkout(args.baseline_rev) as root:
        subprocess.run([sys.executable, __file__, "--child", str(root)], env=gs2e_env(root), check=True)
    rows = [{"n": n, "loop_s": base.wall_s, "numpy_s": new.wall_s}]
    plt = pyplot()
    fig, ax = plt.subplots()
    ax.bar(["loop", "numpy"], [base.wall_s, new.wall_s])
    files = [write_csv("bench_toy", rows), save_plot(fig, "bench_toy")]
    report("n loop_s numpy_s", f"toy: numpy {base.wall_s / new.wall_s:.0f}x the loop", files)


argparse_suppress = "==SUPPRESS=="
if __name__ == "__main__":
    main()
'''


def test_a_toy_benchmark_through_the_harness(tmp_path):
    """The recipe of docs/development.md: flags, clock, a baseline revision's
    checkout whose gs2e a child imports, CSV + plot, the headline last with
    the machine."""
    script = tmp_path / "bench_toy.py"
    script.write_text(TOY)
    out = tmp_path / "results"
    # the toy lives outside benchmarks/: its PYTHONPATH stands in for the script's folder
    env = {**os.environ, "PYTHONPATH": str(BENCH), "GS2E_BENCH_RESULTS": str(out),
           "GS2E_PROGRESS": "0"}
    proc = subprocess.run([sys.executable, str(script), "--quick"], capture_output=True, text=True,
                          env=env, cwd=REPO, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    last = proc.stdout.strip().splitlines()[-1]
    assert last.startswith("toy: numpy ") and "CPUs" in last and last.endswith("]"), last
    assert (out / "bench_toy.csv").read_text().startswith("n,loop_s,numpy_s")
    assert (out / "bench_toy.png").stat().st_size > 1000
    # the child imported the checkout's gs2e, and the worktree is gone again
    root = next(ln.split(" ", 1)[1] for ln in proc.stdout.splitlines() if ln.startswith("checkout "))
    wt = subprocess.run(["git", "worktree", "list"], cwd=REPO, capture_output=True, text=True).stdout
    assert "gs2e_baseline_" in root and root not in wt and not os.path.exists(root)


def test_a_child_with_another_gs2e_is_stopped(tmp_path):
    """check_gs2e_root: a child that imported the wrong gs2e stops with a message."""
    env = {**os.environ, "PYTHONPATH": str(BENCH)}
    code = f"import harness; harness.check_gs2e_root({str(tmp_path)!r})"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode != 0 and f"not the gs2e of {tmp_path}" in proc.stderr


def test_csv_rows_may_have_different_fields(tmp_path, monkeypatch):
    """bench_sim2real --quick stopped with "dict contains fields not in
    fieldnames": the harness takes rows with different fields."""
    import csv
    import importlib

    monkeypatch.setenv("GS2E_BENCH_RESULTS", str(tmp_path))
    monkeypatch.syspath_prepend(str(BENCH))
    import harness

    harness = importlib.reload(harness)
    path = harness.write_csv("mixed", [{"a": 1, "b": 2}, {"a": 3, "c": 4}, {"d": 5}])
    rows = list(csv.DictReader(open(path)))
    assert list(rows[0]) == ["a", "b", "c", "d"]
    assert [(r["a"], r["b"], r["c"], r["d"]) for r in rows] == [("1", "2", "", ""), ("3", "", "4", ""),
                                                                ("", "", "", "5")]


# Scripts whose --quick run needs what this machine may lack (a GPU, the official
# DVS-Voltmeter or other packages of the bench extra), with the reason.
QUICK_NEEDS = {"bench_events_gpu": "a CUDA device", "bench_backend": "a CUDA device (gsplat)"}


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.stem)
def test_quick_run(script):
    """Every benchmark's --quick run ends with its headline (make bench runs
    them all). Slow tier: the first quick runs that need trained models build
    them through the workflow (cached under benchmarks/results/)."""
    proc = subprocess.run([sys.executable, str(script), "--quick"], capture_output=True, text=True,
                          cwd=REPO, env={**os.environ, "GS2E_PROGRESS": "0"}, timeout=4 * 3600)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-3000:]
    if script.stem in QUICK_NEEDS:
        import torch

        if not torch.cuda.is_available():
            return  # it says why it measured nothing, and exits 0
    last = proc.stdout.strip().splitlines()[-1]
    assert last.endswith("]") and "CPUs" in last, last
