"""Scale: the paper's selection (`gs2e scenes`, config/paper.yaml), many-scene
dry-runs, and a workflow run over several real scenes."""

from __future__ import annotations

import math
import time
from pathlib import Path

import pytest

from gs2e.common.errors import ConfigError, InputError
from gs2e.config import load_config, load_scenes, scene_config
from gs2e.io.selection import (SCENE_ID_RE, SceneId, build_rows, parse_id_list, read_id_list,
                               resolve_path, scene_id_for, write_scenes_table)
from tests.conftest import REPO, run_cli, run_snakemake, shared_data


# ---------------------------------------------------------------- id lists

def test_source_files_are_the_regular_files_of_a_capture(tmp_path):
    """ingest's inputs: every regular file below the path, sorted; hidden names,
    dangling links and FIFOs skipped; a linked folder walked once, even in a loop."""
    import os

    from gs2e.io.selection import source_files

    cap = tmp_path / "cap"
    (cap / "images").mkdir(parents=True)
    (cap / "images" / "b.png").write_bytes(b"b")
    (cap / "images" / "a.png").write_bytes(b"a")
    (cap / "poses.json").write_text("{}")
    (cap / ".DS_Store").write_bytes(b"x")
    (cap / ".git").mkdir()
    (cap / ".git" / "HEAD").write_text("ref")
    os.symlink(cap / "gone.png", cap / "images" / "dangling.png")
    os.mkfifo(cap / "pipe")
    other = tmp_path / "shared"
    other.mkdir()
    (other / "calib.txt").write_text("1")
    os.symlink(other, cap / "linked")
    os.symlink(cap, cap / "images" / "loop")  # a link back up the tree
    got = source_files(cap)
    assert got == sorted(str(cap / p) for p in ("images/a.png", "images/b.png", "linked/calib.txt",
                                                  "poses.json"))
    assert source_files(cap / "poses.json") == [str(cap / "poses.json")]
    assert source_files(tmp_path / "missing") == [str(tmp_path / "missing")]
    (tmp_path / "empty").mkdir()
    assert source_files(tmp_path / "empty") == []  # ingest then says it holds no images


def test_parse_id_list_comments_blanks_and_normalisation():
    text = "# header\n\n 7/0a1b2c3d \n26/1f00e8a4   # trailing comment\n26//1f00e8a5/\n"
    ids = parse_id_list(text, "m.txt", "mvimgnet")
    assert [i.id for i in ids] == ["7/0a1b2c3d", "26/1f00e8a4", "26/1f00e8a5"]
    assert [i.where for i in ids] == ["m.txt:3", "m.txt:4", "m.txt:5"]


@pytest.mark.parametrize("bad, why", [
    ("7/../etc", "relative path"),
    ("/abs/clip", "relative path"),
    ("7/clip x", "letters, digits"),
    ("7/clip\tx", "letters, digits"),
    ("a/b/c", "category/clip"),
    ("./clip", "relative path"),
    ("cl;ip", "letters, digits"),
])
def test_bad_ids_are_rejected_naming_file_and_line(bad, why):
    with pytest.raises(InputError, match=rf"ids\.txt:2: .*{why}"):
        parse_id_list(f"7/ok\n{bad}\n", "ids.txt", "mvimgnet")


def test_duplicate_ids_are_rejected_with_both_lines():
    with pytest.raises(InputError, match=r"d\.txt:3: duplicate dl3dv id 'abc' \(first at d\.txt:1\)"):
        parse_id_list("abc\nxyz\nabc/\n", "d.txt", "dl3dv")


def test_scene_ids_collide_after_sanitising():
    a = parse_id_list("7/a_b\n", "a.txt", "mvimgnet")
    b = parse_id_list("7_a/b\n", "b.txt", "mvimgnet")
    with pytest.raises(ConfigError, match=r"b\.txt:1: id '7_a/b' and a\.txt:1: id '7/a_b' both give "
                                          r"scene_id 'mvi_7_a_b'"):
        build_rows([(a, "/r", ""), (b, "/r", "")], check=False)
    # a DL3DV scene is its hash, whichever subset folder it is listed under
    c = parse_id_list("1K/abc\n2K/abc\n", "c.txt", "dl3dv")
    with pytest.raises(ConfigError, match="both give scene_id 'dl3dv_abc'"):
        build_rows([(c, "/r", "")], check=False)


def test_bare_and_full_mvimgnet_id_of_one_clip_collide(tmp_path):
    _mvimgnet_tree(tmp_path, ["26/bbb"])
    ids = parse_id_list("26/bbb\nbbb\n", "m.txt", "mvimgnet")
    with pytest.raises(ConfigError, match="m.txt:2: id 'bbb' and m.txt:1: id '26/bbb' both give scene_id 'mvi_26_bbb'"):
        build_rows([(ids, tmp_path, "")])


def test_scene_ids_match_the_workflow_wildcard():
    for ds, raw in [("mvimgnet", "7/0a1b"), ("mvimgnet", "-x"), ("dl3dv", "1K/.hidden"),
                    ("dl3dv", "_" * 3)]:
        sid = scene_id_for(SceneId(ds, raw, "x:1"))
        assert SCENE_ID_RE.match(sid), sid
    assert scene_id_for(SceneId("mvimgnet", "7/0a1b", "x:1")) == "mvi_7_0a1b"
    # Snakemake refuses wildcard values ending in a 20-fold repeat; caught here with the id's line
    assert scene_id_for(SceneId("dl3dv", "ab" * 19 + "c", "x:1"))
    with pytest.raises(InputError, match="d.txt:4: dl3dv id '1K/f0+' .*repeated pattern"):
        scene_id_for(SceneId("dl3dv", "1K/f" + "0" * 63, "d.txt:4"))
    assert scene_id_for(SceneId("dl3dv", "1K/ff00", "x:1")) == "dl3dv_ff00"


def test_empty_list_is_an_error(tmp_path):
    f = tmp_path / "ids.txt"
    f.write_text("# only comments\n\n")
    with pytest.raises(InputError, match="ids.txt has no ids"):
        read_id_list(f, "mvimgnet")
    with pytest.raises(InputError, match="cannot read"):
        read_id_list(tmp_path / "absent.txt", "dl3dv")


# ---------------------------------------------------------------- paths

def _mvimgnet_tree(root: Path, ids: list[str]) -> None:
    for i in ids:
        (root / i / "images").mkdir(parents=True)
        (root / i / "sparse" / "0").mkdir(parents=True)


def _dl3dv_tree(root: Path, ids: list[str], nerfstudio: bool = False) -> None:
    for i in ids:
        d = root / i / ("nerfstudio" if nerfstudio else "")
        (d / "images_4").mkdir(parents=True)
        (d / "transforms.json").write_text("{}")


def test_resolve_paths_by_dataset_conventions(tmp_path):
    mvi, dl = tmp_path / "mvi", tmp_path / "dl3dv"
    _mvimgnet_tree(mvi, ["7/aaa", "26/bbb"])
    _dl3dv_tree(dl, ["h1"])
    _dl3dv_tree(dl, ["1K/h2"], nerfstudio=True)
    assert resolve_path(SceneId("mvimgnet", "7/aaa", "m:1"), mvi) == mvi / "7" / "aaa"
    # a bare clip id is found under its category
    assert resolve_path(SceneId("mvimgnet", "bbb", "m:2"), mvi) == mvi / "26" / "bbb"
    assert resolve_path(SceneId("dl3dv", "h1", "d:1"), dl) == dl / "h1"
    assert resolve_path(SceneId("dl3dv", "h2", "d:2"), dl) == dl / "1K" / "h2"
    # without checking, a bare MVImgNet clip cannot be placed
    with pytest.raises(InputError, match="m:3: mvimgnet id 'ccc' has no category"):
        resolve_path(SceneId("mvimgnet", "ccc", "m:3"), mvi, check=False)
    assert resolve_path(SceneId("dl3dv", "nope", "d:3"), dl, check=False) == dl / "nope"


def test_ambiguous_and_incomplete_folders(tmp_path):
    mvi = tmp_path / "mvi"
    _mvimgnet_tree(mvi, ["1/dup", "2/dup"])
    (mvi / "3" / "noimg").mkdir(parents=True)
    with pytest.raises(InputError, match="'dup' matches several folders"):
        resolve_path(SceneId("mvimgnet", "dup", "m:1"), mvi)
    with pytest.raises(InputError, match=r"m:2: mvimgnet id '3/noimg': .*noimg has no images/"):
        resolve_path(SceneId("mvimgnet", "3/noimg", "m:2"), mvi)
    dl = tmp_path / "dl"
    (dl / "h0" / "images_2").mkdir(parents=True)
    with pytest.raises(InputError, match=r"h0 has no transforms\.json"):
        resolve_path(SceneId("dl3dv", "h0", "d:1"), dl)


def test_missing_paths_error_names_every_id_and_path(tmp_path):
    mvi = tmp_path / "mvi"
    _mvimgnet_tree(mvi, ["7/aaa"])
    ids = parse_id_list("7/aaa\n7/gone\n9/lost\n", "m.txt", "mvimgnet")
    with pytest.raises(InputError) as exc:
        build_rows([(ids, mvi, "")])
    msg = str(exc.value)
    assert msg.startswith("2 scene(s) not found")
    assert f"m.txt:2: mvimgnet id '7/gone': folder {mvi / '7' / 'gone'} does not exist" in msg
    assert f"m.txt:3: mvimgnet id '9/lost': folder {mvi / '9' / 'lost'} does not exist" in msg
    assert "7/aaa" not in msg


# ---------------------------------------------------------------- the table and the CLI

def test_cli_writes_a_table_load_scenes_accepts(tmp_path):
    mvi, dl = tmp_path / "mvi", tmp_path / "dl3dv"
    _mvimgnet_tree(mvi, ["7/aaa", "26/bbb"])
    h = "3f8a9c0d2b7e41f6a5c9d8e7b6a5f4e3d2c1b0a99887766554433221100ffeed"  # hash-like
    _dl3dv_tree(dl, ["1K/" + h])
    (tmp_path / "m.txt").write_text("# mine\n7/aaa\nbbb\n")
    (tmp_path / "d.txt").write_text("1K/" + h + "\n")
    out = tmp_path / "cfg" / "paper_scenes.tsv"
    run_cli("scenes", "--mvimgnet-root", str(mvi), "--mvimgnet-ids", str(tmp_path / "m.txt"),
            "--dl3dv-root", str(dl), "--dl3dv-ids", str(tmp_path / "d.txt"),
            "--overrides-dl3dv", "ingest.max_views=100;ingest.max_side=960",
            "--out", str(out), check=True)
    rows = load_scenes(out)
    assert [(r["scene_id"], r["layout"], r["path"]) for r in rows] == [
        ("mvi_7_aaa", "mvimgnet", str(mvi / "7" / "aaa")),
        ("mvi_26_bbb", "mvimgnet", str(mvi / "26" / "bbb")),
        ("dl3dv_" + h, "dl3dv", str(dl / "1K" / h)),
    ]
    cfg = load_config({})
    assert scene_config(cfg, rows[0])["ingest"]["max_views"] == 30  # the paper's N
    assert scene_config(cfg, rows[2])["ingest"]["max_side"] == 960


def test_cli_errors_leave_no_output(tmp_path):
    (tmp_path / "m.txt").write_text("7/aaa\n")
    out = tmp_path / "t.tsv"
    p = run_cli("scenes", "--mvimgnet-root", str(tmp_path / "none"), "--mvimgnet-ids",
                str(tmp_path / "m.txt"), "--out", str(out))
    assert p.returncode == 2 and "7/aaa" in p.stderr and str(tmp_path / "none" / "7" / "aaa") in p.stderr
    p = run_cli("scenes", "--mvimgnet-root", str(tmp_path), "--mvimgnet-ids", str(tmp_path / "m.txt"),
                "--overrides-mvimgnet", "ingest.max_viewz=3", "--no-check", "--out", str(out))
    assert p.returncode == 2 and "ingest.max_viewz" in p.stderr
    p = run_cli("scenes", "--mvimgnet-ids", str(tmp_path / "m.txt"), "--out", str(out))
    assert p.returncode == 2 and "--mvimgnet-root" in p.stderr
    assert not out.exists() and not list(tmp_path.glob(".t*"))


def test_write_keeps_the_old_table_on_bad_overrides(tmp_path):
    out = tmp_path / "t.tsv"
    out.write_text("old\n")
    rows = [{"scene_id": "a", "layout": "folder", "path": "/x", "overrides": "splat.max_iterations=-1"}]
    with pytest.raises(ConfigError, match="splat.max_iterations"):
        write_scenes_table(rows, out)
    assert out.read_text() == "old\n"


def test_paper_config_and_example_ids():
    cfg = load_config(REPO / "config" / "paper.yaml")
    assert cfg["splat"]["max_iterations"] == 30000
    assert cfg["trajectory"]["gamma"] == 5 and cfg["trajectory"]["mini_frames"] == 150
    assert cfg["events"]["sampling"]["mode"] == "fixed" and cfg["events"]["sampling"]["fixed_fps"] == 2400
    assert cfg["events"]["theta_on"] == cfg["events"]["theta_off"] == 1.0
    m = read_id_list(REPO / "config" / "paper_ids" / "mvimgnet.example.txt", "mvimgnet")
    d = read_id_list(REPO / "config" / "paper_ids" / "dl3dv.example.txt", "dl3dv")
    assert len(m) >= 3 and len(d) >= 2
    assert all("/" in i.id for i in m)  # usable with --no-check


def test_paper_selection_dry_run(tmp_path):
    """The example ids through `gs2e scenes` and a dry-run of config/paper.yaml:
    every scene gets the paper's 4 trajectories x (render, events)."""
    ids_dir = REPO / "config" / "paper_ids"
    mvi, dl = tmp_path / "mvi", tmp_path / "dl3dv"
    _mvimgnet_tree(mvi, [i.id for i in read_id_list(ids_dir / "mvimgnet.example.txt", "mvimgnet")])
    _dl3dv_tree(dl, [i.id for i in read_id_list(ids_dir / "dl3dv.example.txt", "dl3dv")])
    table = tmp_path / "paper_scenes.tsv"
    run_cli("scenes", "--mvimgnet-root", str(mvi), "--mvimgnet-ids", str(ids_dir / "mvimgnet.example.txt"),
            "--dl3dv-root", str(dl), "--dl3dv-ids", str(ids_dir / "dl3dv.example.txt"),
            "--out", str(table), check=True)
    n = len(load_scenes(table))
    t0 = time.perf_counter()
    p = run_snakemake("-n", "--quiet", "rules", "--directory", str(tmp_path),
                      "--configfile", str(REPO / "config" / "paper.yaml"),
                      "--config", f"scenes={table}", timeout=300)
    wall = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr[-3000:]
    counts = {}
    for line in p.stdout.splitlines():
        parts = line.split()
        if len(parts) == 2 and parts[1].isdigit():
            counts[parts[0]] = int(parts[1])
    assert counts["render"] == counts["events"] == 4 * n
    assert counts["ingest"] == counts["sfm"] == counts["train"] == n
    print(f"paper-selection dry run: {n} scenes in {wall:.1f} s")  # speed: benchmarks/bench_dryrun.py


def test_dry_run_over_many_scenes_is_bounded(tmp_path):
    """The scheduler holds the DAG (a few hundred kB per scene), never scene data:
    its peak RSS over 300 scenes stays far below one scene's job, and every job is
    planned. Its speed is measured by benchmarks/bench_dryrun.py, not asserted here."""
    import os
    import subprocess

    n = 300
    ids = [f"{i % 238}/{i:08x}" for i in range(n)]
    for i in ids:
        (tmp_path / "mvi" / i / "images").mkdir(parents=True)
    (tmp_path / "ids.txt").write_text("\n".join(ids) + "\n")
    table = tmp_path / "scenes.tsv"
    run_cli("scenes", "--mvimgnet-root", str(tmp_path / "mvi"), "--mvimgnet-ids", str(tmp_path / "ids.txt"),
            "--out", str(table), check=True)
    from tests.conftest import BIN

    cmd = [str(BIN / "snakemake"), "--snakefile", str(REPO / "Snakefile"), "-n", "--quiet", "rules",
           "--directory", str(tmp_path), "--config", f"scenes={table}"]
    env = {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}"}
    # Peak memory from the process's own VmHWM: rusage's ru_maxrss of a child
    # also counts the (large) pytest process it was forked from.
    t0 = time.perf_counter()
    peak_kb = 0
    with open(tmp_path / "out.txt", "w") as fh:
        proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=fh, stderr=subprocess.STDOUT, env=env)
        while proc.poll() is None:
            try:
                status_txt = Path(f"/proc/{proc.pid}/status").read_text()
                peak_kb = max(peak_kb, int(status_txt.split("VmHWM:")[1].split()[0]))
            except (OSError, IndexError, ValueError):
                pass
            time.sleep(0.05)
    wall = time.perf_counter() - t0
    out = (tmp_path / "out.txt").read_text()
    assert proc.returncode == 0, out[-3000:]
    n_traj = len(load_config({})["render"]["trajectories"])
    # per scene: ingest, sfm, train, trajectory, render + events + windows per
    # trajectory, the model's and the scene's quality gates, metrics; + summary, datasheet,
    # report, all
    assert f"total {(7 + 3 * n_traj) * n + 4}" in " ".join(out.split())
    print(f"dry run: {n} scenes in {wall:.1f} s, peak {peak_kb / 1024:.0f} MB")
    assert 0 < peak_kb / 1024 < 600, peak_kb  # MB; 1-scene dry-run ~160 MB, 1050 scenes ~330 MB


# ---------------------------------------------------------------- real scenes

REAL_OVERRIDES = ";".join([
    "ingest.max_side=320", "sfm.max_num_features=2048",
    "splat.max_iterations=200", "splat.min_iterations=200", "splat.eval_every=100",
    "splat.densify_from=40", "splat.densify_until=150", "splat.densify_every=20",
    "splat.resolution_schedule=[[0,2],[100,1]]", "splat.checkpoint_every=0",
    "trajectory.speed_presets=[medium]", "trajectory.mini_groups=1", "trajectory.mini_frames=30",
    "trajectory.plot=false",
    "render.trajectories=[mini00_medium]", "render.fps=10", "render.exposure_us=20000",
    "events.max_duration_s=0.05", "render.min_coverage=0.0",
    "events.model=ideal", "events.theta_on=0.3", "events.theta_off=0.3", "events.preview=false",
])
JOB_MEM_BOUND_MB = 1500  # per job: one scene's data (320x240 views, <= a few 10k Gaussians)


def read_benchmarks(results: Path) -> dict[tuple[str, str], dict]:
    """{(scene, job): results/<scene>/benchmarks/<job>.tsv as floats}."""
    from gs2e.report.io import read_results_benchmarks

    return {(r["scene"], r["job"]): r for r in read_results_benchmarks(results) if r["scene"]}


@pytest.mark.slow
def test_workflow_over_real_scenes(tmp_path):
    """temple_ring (47 views, Middlebury ring) and llff_fern (20 views), both as plain
    image folders (full SfM), tiny budgets: the summary has both scenes and no job
    holds more than one scene's worth of memory."""
    temple = shared_data("temple_ring")
    fern = shared_data("llff_fern", "images")
    (tmp_path / "scenes.tsv").write_text(
        "scene_id\tlayout\tpath\toverrides\n"
        f"temple_ring\tfolder\t{temple}\t{REAL_OVERRIDES}\n"
        f"llff_fern\tfolder\t{fern}\t{REAL_OVERRIDES}\n")
    t0 = time.perf_counter()
    p = run_snakemake("--cores", "2", "--directory", str(tmp_path),
                      "--config", f"scenes={tmp_path / 'scenes.tsv'}", timeout=1500)
    wall = time.perf_counter() - t0
    assert p.returncode == 0, p.stderr[-5000:]
    import pandas as pd

    df = pd.read_parquet(tmp_path / "results" / "summary.parquet")
    assert sorted(df["scene_id"]) == ["llff_fern", "temple_ring"]
    assert df["train_test_psnr"].map(math.isfinite).all(), df["train_test_psnr"]
    assert (df["train_test_psnr"] > 10).all(), df["train_test_psnr"]
    assert (df["events_n_events"] > 0).all(), df["events_n_events"]
    assert (df["sfm_registration_rate"] >= 0.8).all()
    html = (tmp_path / "results" / "report.html").read_text()
    assert "temple_ring" in html and "llff_fern" in html
    bench = read_benchmarks(tmp_path / "results")
    jobs = {j for _, j in bench}
    assert {"ingest", "sfm", "train", "trajectory", "render_mini00_medium",
            "events_mini00_medium", "windows_mini00_medium", "metrics"} <= jobs
    assert len(bench) == 2 * 8
    rss = {k: v["max_rss"] for k, v in bench.items()}
    assert max(rss.values()) < JOB_MEM_BOUND_MB, rss
    print(f"\nreal scenes: wall {wall:.0f} s")
    for (scene, job), v in sorted(bench.items()):
        print(f"{scene:12s} {job:22s} {v['s']:7.1f} s  cpu {v['cpu_time']:7.1f} s  "
              f"max_rss {v['max_rss']:7.0f} MB")
