"""Exact CPU time and peak memory per job: every gs2e command ends its log with
getrusage's figures, and the benchmark readers prefer them to Snakemake's
sampled ones (which lose what a job does after its last sample, up to 30 s)."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from gs2e.report.io import read_benchmark_file, read_job_usage, read_results_benchmarks
from tests.conftest import BIN

BURN = textwrap.dedent("""
    import subprocess, sys, threading, time
    import numpy as np
    from gs2e.common.log import process_usage

    def burn(s):
        t = time.thread_time()
        while time.thread_time() - t < s:
            pass

    # a child that burns 0.4 CPU-s, then two threads of this process 0.3 s each
    subprocess.run([sys.executable, "-c",
                    "import time\\nt=time.process_time()\\nwhile time.process_time()-t<0.4: pass"],
                   check=True)
    ts = [threading.Thread(target=burn, args=(0.3,)) for _ in range(2)]
    [t.start() for t in ts]
    [t.join() for t in ts]
    a = np.ones(300 * 2**20 // 8)  # 300 MB, touched
    cpu_s, peak_mb = process_usage()
    print(cpu_s, peak_mb)
""")


def test_process_usage_counts_every_thread_children_and_the_peak():
    # Through an intermediate process: a child spawned straight from pytest shares
    # pytest's memory until it execs, and Linux keeps that peak in the child's
    # ru_maxrss (over 2 GB late in a full run), which is not what is tested here.
    spawn = "import subprocess, sys; sys.exit(subprocess.run([sys.executable, '-c', sys.argv[1]]).returncode)"
    out = subprocess.run([sys.executable, "-c", spawn, BURN], check=True, capture_output=True, text=True)
    cpu_s, peak_mb = map(float, out.stdout.split())
    assert cpu_s >= 0.4 + 2 * 0.3 - 0.02  # both threads and the waited-for child
    assert cpu_s < 10
    assert 300 <= peak_mb < 2000


def test_usage_lines_are_summed_over_the_commands_of_a_job(tmp_path):
    log = tmp_path / "x.log"
    log.write_text("12:00:00 INFO gs2e: gs2e render finished in 2.50 s (4.00 CPU-s, peak RSS 500.0 MB)\n"
                   "noise\n"
                   "12:00:03 INFO gs2e: gs2e events finished in 1.00 s (1.50 CPU-s, peak RSS 700.5 MB)\n")
    assert read_job_usage(log) == {"wall_s": 3.5, "cpu_s": 5.5, "max_rss_mb": 700.5}
    log.write_text("gs2e events finished in 1.00 s\n")  # a log of an older gs2e, or a failed job
    assert read_job_usage(log) is None
    assert read_job_usage(tmp_path / "absent.log") is None


def test_snakemake_job_reads_its_exact_usage_from_the_log(tmp_path):
    """A real Snakemake run of a rule with log: and benchmark: as the workflow's rules
    have them: the benchmark row carries the CPU seconds the gs2e command logged."""
    (tmp_path / "Snakefile").write_text(textwrap.dedent(f"""
        rule presets:
            output: "res/sc/presets.txt"
            log: "res/sc/logs/presets.log"
            benchmark: "res/sc/benchmarks/presets.tsv"
            shell: "{BIN / 'gs2e'} events-presets > {{output}} 2> {{log}}"
    """))
    proc = subprocess.run([str(BIN / "snakemake"), "--cores", "1", "--quiet", "all"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    usage = read_job_usage(tmp_path / "res/sc/logs/presets.log")
    assert usage is not None and usage["cpu_s"] > 0.1 and usage["max_rss_mb"] > 30
    row = read_benchmark_file(tmp_path / "res/sc/benchmarks/presets.tsv")
    assert row["usage_exact"] == 1.0
    assert row["cpu_time"] == pytest.approx(usage["cpu_s"]) and row["max_rss"] == pytest.approx(usage["max_rss_mb"])
    assert "cpu_time_sampled" in row and "max_rss_sampled" in row
    [r] = read_results_benchmarks(tmp_path / "res")
    assert (r["scene"], r["job"], r["cpu_time"]) == ("sc", "presets", row["cpu_time"])
    # without the usage line, Snakemake's own samples stay
    (tmp_path / "res/sc/logs/presets.log").write_text("")
    row = read_benchmark_file(tmp_path / "res/sc/benchmarks/presets.tsv")
    assert row["usage_exact"] == 0.0 and "cpu_time_sampled" not in row


def test_the_usage_line_is_the_whole_process(tmp_path):
    """The program ends right after its usage line (no interpreter teardown after
    it: ~0.3-0.5 CPU-s once torch or numba are loaded), so the line holds all the
    CPU time the process used."""
    import os
    import re
    import resource

    import numpy as np

    frames = np.random.default_rng(0).random((5, 24, 32)).astype(np.float32)
    np.save(tmp_path / "frames.npy", frames)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    p = subprocess.run([str(BIN / "gs2e"), "events", str(tmp_path / "frames.npy"), "--fps", "100",
                        "--encoding", "linear", "-o", str(tmp_path / "ev")],
                       capture_output=True, text=True, env={**os.environ, "GS2E_PROGRESS": "0"})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert p.returncode == 0, p.stderr[-2000:]
    assert (tmp_path / "ev" / "events.h5").is_file()  # written and closed before the exit
    measured = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    logged = float(re.search(r"\(([0-9.]+) CPU-s, peak RSS", p.stderr).group(1))
    assert logged <= measured + 0.02
    assert measured - logged < 0.1, (measured, logged)
