"""The Snakemake workflow: dry-runs, validation before any job, wiring."""

from __future__ import annotations

from pathlib import Path

from tests.conftest import REPO, run_snakemake


def _scenes(tmp_path: Path, rows: list[str]) -> Path:
    p = tmp_path / "scenes.tsv"
    p.write_text("scene_id\tlayout\tpath\toverrides\n" + "\n".join(rows) + "\n")
    return p


def test_dry_run_default_config(tmp_path):
    # the checkout's own config; results elsewhere, so a `make demo` already run here
    # (results/ in the checkout) does not empty the plan
    proc = run_snakemake("-n", "--cores", "2", "--directory", str(REPO),
                         "--config", f"results_dir={tmp_path / 'results'}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    for rule in ("demo_scene", "ingest", "sfm"):
        assert rule in out


def test_dry_run_in_other_directory_with_overrides(tmp_path):
    scenes = _scenes(tmp_path, ["d1\tdemo\t\tdemo.n_views=12", "d2\tdemo\t\t"])
    proc = run_snakemake("-n", "--cores", "1", "--directory", str(tmp_path),
                         "--config", f"scenes={scenes}", "results_dir=out")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "out/d1/sfm" in proc.stdout and "out/d2/sfm" in proc.stdout


def test_invalid_config_rejected_before_any_job(tmp_path):
    scenes = _scenes(tmp_path, ["d1\tdemo\t\t"])
    proc = run_snakemake("--cores", "1", "--directory", str(tmp_path),
                         "--config", f"scenes={scenes}", "sfm={'matcher': 'bogus'}")
    assert proc.returncode != 0
    assert "sfm.matcher" in proc.stderr
    assert not (tmp_path / "results").exists()


def test_invalid_scene_override_rejected(tmp_path):
    scenes = _scenes(tmp_path, ["d1\tdemo\t\tsfm.min_registered_fraction=2"])
    proc = run_snakemake("-n", "--cores", "1", "--directory", str(tmp_path),
                         "--config", f"scenes={scenes}")
    assert proc.returncode != 0
    out = proc.stdout + proc.stderr
    assert "sfm.min_registered_fraction" in out and "'d1'" in out


def test_every_rule_has_log_benchmark_and_code_version():
    import re

    rules = []
    for p in sorted((REPO / "workflow" / "rules").glob("*.smk")):
        rules += re.split(r"\nrule ", "\n" + p.read_text())[1:]
    assert rules
    for body in rules:
        name = body.split(":", 1)[0]
        for directive in ("log:", "benchmark:", "code=code_version(", "conda:"):
            assert directive in body, f"rule {name} lacks {directive}"
        shell = body.split("shell:", 1)[1] if "shell:" in body else ""
        # config values reach the CLI through params only, never interpolated into shell.
        assert "config[" not in shell and "SCENE_CFG" not in shell, name


def test_conda_env_covers_the_package_dependencies():
    """envs/gs2e.yaml (used by `snakemake --sdm conda`) lists every runtime
    dependency of pyproject.toml (conda-forge names where they differ)."""
    import re
    import tomllib

    import yaml

    env = yaml.safe_load((REPO / "envs" / "gs2e.yaml").read_text())
    names = set()
    for dep in env["dependencies"]:
        items = dep["pip"] if isinstance(dep, dict) else [dep]
        for item in items:
            names.add(re.split(r"[<>=!\s]", item, maxsplit=1)[0].lower())
    conda_name = {"torch": "pytorch", "opencv-contrib-python-headless": "py-opencv",
                  "snakemake": None, "snakemake-executor-plugin-slurm": None}
    deps = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["dependencies"]
    for dep in deps:
        name = re.split(r"[<>=!\s\[]", dep, maxsplit=1)[0].lower()
        want = conda_name.get(name, name)
        if want is not None:  # snakemake itself runs outside the job environment
            assert want in names, f"envs/gs2e.yaml lacks {want} (pyproject: {dep})"


def test_bench_jobs_follow_bench_tasks(tmp_path):
    """bench.tasks adds one job per trajectory x task and the dataset table; off, none."""
    from tests.conftest import planned_jobs

    scenes = _scenes(tmp_path, ["on\tdemo\t\tbench.tasks=[deblur,video,recon3d];"
                                "render.trajectories=[base_mild,base_strong]", "off\tdemo\t\t"])
    proc = run_snakemake("-n", "--cores", "2", "--directory", str(tmp_path),
                         "--config", f"scenes={scenes}", "results_dir=out")
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = planned_jobs(proc.stdout)
    assert jobs["bench"] == 6 and jobs["bench_summary"] == 1
    assert "out/on/bench/deblur/base_strong.parquet" in proc.stdout
    assert "out/on/bench/recon3d/base_mild.parquet" in proc.stdout
    # recon3d trains (two threads), the other tasks score frames (one); each has its own seed
    blocks = proc.stdout.split("\n\n")
    r3 = [b for b in blocks if "bench/recon3d/base_mild.parquet" in b and "rule bench:" in b]
    assert r3 and "threads: 2" in r3[0]
    assert "out/off/bench/" not in proc.stdout
    scenes = _scenes(tmp_path, ["off\tdemo\t\t"])
    proc = run_snakemake("-n", "--cores", "1", "--directory", str(tmp_path),
                         "--config", f"scenes={scenes}", "results_dir=out")
    assert proc.returncode == 0 and "bench" not in planned_jobs(proc.stdout)


def test_sensor_choice_never_reaches_ingest_or_sfm(tmp_path):
    """Structure from motion sees the photos, not the event sensor: for the real
    captures (a turntable object, a forward-facing scene, a phone capture of
    mixed orientation) and every sensor preset, the ingest and sfm jobs are the
    same commands, so the same views register; only training (the size that
    covers the sensor), frames and events change."""
    import re

    from gs2e.events.sensors import SENSORS
    from tests.conftest import shared_data

    rows = [f"temple_ring\tfolder\t{shared_data('temple_ring')}\t",
            f"llff_fern\tfolder\t{shared_data('llff_fern', 'images')}\t",
            f"mouse_colmap\tcolmap\t{shared_data('mouse_colmap')}\t"]
    jobs = {}
    for sensor in ["null", *SENSORS]:
        scenes = _scenes(tmp_path, [r + f"events.sensor={sensor}" for r in rows])
        proc = run_snakemake("-n", "-p", "--cores", "2", "--directory", str(tmp_path),
                             "--config", f"scenes={scenes}", "results_dir=out")
        assert proc.returncode == 0, proc.stderr[-3000:]
        shells = {}
        for block in proc.stdout.split("\n\n"):
            m = re.search(r"rule (ingest|sfm|train):", block)
            scene = re.search(r"out/(\w+)/", block)
            if m and scene:
                shells[(m.group(1), scene.group(1))] = block[block.index("\n", block.index("reason")):]
        assert len(shells) == 9, sorted(shells)
        jobs[sensor] = shells
    for sensor in SENSORS:
        for key, cmd in jobs[sensor].items():
            if key[0] == "train":  # the sensor's size reaches training, and only training
                assert cmd != jobs["null"][key] and "--target-size" in cmd
            else:
                assert cmd == jobs["null"][key], (sensor, key)


def test_capture_copied_anew_reruns_nothing_unless_its_bytes_change(tmp_path):
    """ingest's inputs are the capture's files (gs2e.io.selection.source_files), so
    Snakemake judges a copy by content: every file newer than the results but with
    the bytes it had when ingest ran (a re-staged dataset) reruns nothing, a file
    over Snakemake's 1 MB default included (the workflow profile raises the size it
    checks, as gs2e dataset passes it); a changed byte or an added file reruns ingest."""
    import os
    import time

    import cv2
    import numpy as np

    from gs2e.dataset.run import MAX_CHECKSUM_FILE_BYTES
    from tests.conftest import planned_jobs

    src = tmp_path / "capture"
    (src / "images").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(src / "images" / f"{i:02d}.png"), rng.integers(0, 256, (24, 32, 3), dtype=np.uint8))
    (src / "poses.bin").write_bytes(rng.integers(0, 256, 1_500_000, dtype=np.uint8).tobytes())
    (src / ".DS_Store").write_bytes(b"finder")
    scenes = _scenes(tmp_path, [f"cap\tfolder\t{src}\t"])
    args = ("--cores", "1", "--max-checksum-file-size", str(MAX_CHECKSUM_FILE_BYTES), "--directory",
            str(tmp_path), "--config", f"scenes={scenes}", "results_dir=out")
    target = "out/cap/ingest"
    done = run_snakemake(target, *args)  # targets first: --config takes every word after it
    assert done.returncode == 0, done.stderr[-3000:]

    def planned() -> dict[str, int]:
        proc = run_snakemake(target, "-n", *args)
        assert proc.returncode == 0, proc.stderr[-3000:]
        return planned_jobs(proc.stdout) if "Job stats:" in proc.stdout else {}

    later = time.time() + 3600
    for root, dirs, files in os.walk(src):
        for name in dirs + files + [""]:
            os.utime(os.path.join(root, name), (later, later))
    assert planned() == {}
    (src / ".DS_Store").write_bytes(b"finder, again")  # hidden: not an input
    assert planned() == {}
    image = src / "images" / "01.png"
    data = bytearray(image.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size, same (newer) mtime as every other file
    image.write_bytes(bytes(data))
    os.utime(image, (later, later))
    assert planned() == {"ingest": 1}
    image.write_bytes(bytes(data[:len(data) // 2]) + bytes([data[len(data) // 2] ^ 0xFF]) + bytes(data[len(data) // 2 + 1:]))
    assert planned() == {}  # the bytes it was ingested from
    (src / "images" / "03.png").write_bytes(image.read_bytes())
    assert planned() == {"ingest": 1}
