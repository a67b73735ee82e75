"""Bad and unusual inputs, given as a careless user gives them.

Every probe runs one ``gs2e`` command (in-process, through ``gs2e.cli.main``,
exactly as the console script does) on an input made for it and checks what the
user sees: exit status 2, exactly one ``gs2e <command>: error: ...`` line on
stderr that names the file or config key, no traceback, and no partial output
(neither the output nor a temporary of it). Valid but unusual inputs (no
events, one frame, negative timestamps, frames numbered 1..12) are checked to
give valid results instead.

``python tests/test_bad_inputs.py`` prints the probe table of docs/reliability.md,
"What a user sees" (each probe with the message a user sees).
"""

from __future__ import annotations

import io
import json
import os
import re
import sys
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pytest

if __name__ == "__main__":  # the table script: make `tests` importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gs2e.cli import main
from tests._io_synth import make_scene, write_images, write_rgb

os.environ.setdefault("GS2E_PROGRESS", "0")
ERROR_LINE = re.compile(r"^gs2e[ \w-]*: (error|interrupted): .+")


def gs2e(*argv: str) -> tuple[int, str, str]:
    """Run ``gs2e ARGV`` in this process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        try:
            rc = main([str(a) for a in argv])
        except SystemExit as exc:  # argparse
            rc = exc.code
    return rc, out.getvalue(), err.getvalue()


def error_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ERROR_LINE.match(ln)]


def temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".tmp-" in p.name or ".old-" in p.name] \
        if folder.is_dir() else []


# ---------------------------------------------------------------- inputs
def _yaml(tmp: Path, text: str) -> str:
    p = tmp / "config.yaml"
    p.write_text(text)
    return str(p)


def _scene(tmp: Path, n: int = 4, points: int = 20, poses: bool = True, w: int = 32, h: int = 24) -> Path:
    """An internal-layout scene folder (random images, ring poses, points)."""
    from gs2e.io.scene import write_scene_json

    scene = make_scene(n, w, h, points=points)
    from gs2e.io.scene import Camera

    for f in scene.frames:
        f.camera = Camera(30.0, 30.0, w / 2, h / 2)
        if not poses:
            f.c2w = None
    d = tmp / "scene"
    write_images(d / "images", [f.name for f in scene.frames], w, h)
    write_scene_json(scene, d)
    return d


def _frames(tmp: Path, n: int = 4, names: list[str] | None = None, size=(16, 12), values=None,
            folder: str = "frames") -> Path:
    """A folder of grey PNG frames (values: one grey level 0..255 per frame)."""
    d = tmp / folder
    d.mkdir(parents=True, exist_ok=True)
    names = names or [f"f{i:03d}.png" for i in range(n)]
    values = values if values is not None else [40 + 30 * i for i in range(len(names))]
    for nm, v in zip(names, values):
        write_rgb(d / nm, np.full((size[1], size[0], 3), v, np.uint8))
    return d


def _huge_png(p: Path) -> Path:
    """A PNG whose header declares 100000x100000 RGB pixels (no pixel data): a
    decoder would try to allocate 30 GB."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", 100000, 100000, 8, 2, 0, 0, 0)
    _write(p, b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))
    return p.parent


def _model(tmp: Path) -> Path:
    from gs2e.testing import plane_model

    return plane_model(tmp)


def _trajectory(tmp: Path) -> Path:
    from gs2e.testing import straight_trajectory

    return straight_trajectory(tmp, dx=0.2)


def _write(p: Path, data: bytes | str) -> Path:
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_bytes(data.encode() if isinstance(data, str) else data)
    return p


def _empty_recording(p: Path) -> Path:
    from gs2e.events.containers import write_container
    from gs2e.events.models import Events

    write_container(p, "aedat4", Events.empty(), 64, 48)
    return p


def _truncate(p: Path, keep: float = 0.5) -> Path:
    b = p.read_bytes()
    p.write_bytes(b[: int(len(b) * keep)])
    return p


def _nan_pose(scene: Path) -> Path:
    data = json.loads((scene / "scene.json").read_text())
    data["frames"][1]["c2w"][0][3] = float("nan")
    (scene / "scene.json").write_text(json.dumps(data))  # writes the NaN token
    return scene


def _empty_ply(tmp: Path) -> Path:
    from plyfile import PlyData, PlyElement

    from gs2e.common.atomic import write_json_atomic

    m = tmp / "empty_model"
    m.mkdir()
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1",
             "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    vertex = np.empty(0, dtype=[(nm, "<f4") for nm in names])
    PlyData([PlyElement.describe(vertex, "vertex")]).write(str(m / "pc.ply"))
    write_json_atomic(m / "model.json", {"format": "gs2e-splat", "version": 1, "ply": "pc.ply",
                                         "iterations": 0, "sh_degree": 0})
    return m


def _gate_scene(t: Path) -> Path:
    """A finished scene's stats files (SfM, training), without events."""
    _write(t / "s" / "sfm" / "sfm_stats.json", '{"n_views": 10, "n_registered": 10}')
    _write(t / "s" / "splat" / "train_stats.json", '{"test_psnr": 12.5, "test_ssim": 0.5}')
    return t / "s"


# ---------------------------------------------------------------- the probes
@dataclass
class Probe:
    id: str
    what: str                                  # the careless thing (docs/reliability.md table)
    make: Callable[[Path], list]               # builds inputs in a folder, returns argv
    needles: tuple[str, ...]                   # the message names these (file, key)
    out: str | None = "out"                    # output (under the folder) that must not appear


def cfg_probe(pid, what, text, *needles):
    return Probe(pid, what, lambda t: ["config", "--validate", _yaml(t, text)], needles, None)


PROBES = [
    # ---- config values (gs2e config --validate; the Snakefile runs the same checks)
    cfg_probe("cfg-nan", "NaN as a number", "render:\n  fps: .nan\n", "render.fps", "finite"),
    cfg_probe("cfg-inf", "infinity as a threshold", "events:\n  theta_on: .inf\n", "events.theta_on"),
    cfg_probe("cfg-inf-list", "-inf inside a list", "render:\n  background: [0, -.inf, 0]\n",
              "render.background.1"),
    cfg_probe("cfg-string-number", "a number in quotes", "render:\n  fps: '30'\n", "render.fps"),
    cfg_probe("cfg-typo", "a misspelt key", "render:\n  fsp: 30\n", "render.fsp"),
    cfg_probe("cfg-exposure", "exposure longer than the frame interval",
              "render:\n  fps: 100\n  exposure_us: 20000\n", "render.exposure_us", "render.fps"),
    cfg_probe("cfg-velocity-syntax", "unbalanced parenthesis in the velocity",
              "trajectory:\n  velocity: '0.25*sin(t'\n", "trajectory.velocity"),
    cfg_probe("cfg-velocity-negative", "a velocity that goes negative",
              "trajectory:\n  velocity: 't - 0.5'\n", "trajectory.velocity", "positive"),
    cfg_probe("cfg-velocity-pole", "a velocity with a pole at t = 0",
              "trajectory:\n  velocity: '1/t'\n", "trajectory.velocity"),
    cfg_probe("cfg-velocity-code", "Python code as the velocity",
              "trajectory:\n  velocity: \"__import__('os').system('ls')\"\n", "trajectory.velocity"),
    cfg_probe("cfg-speed-list-zero", "a zero in the speed list",
              "trajectory:\n  speed_list: [1, 0]\n", "trajectory.speed_list"),
    cfg_probe("cfg-trajectory-name", "rendering a trajectory that is never made (the demo renders all three speeds)",
              "trajectory:\n  speed_presets: [medium]\n", "render.trajectories", "base_mild"),
    cfg_probe("cfg-light-run", "a run under a lighting condition that does not exist",
              "render:\n  trajectories: [base_medium@dusk]\n", "render.trajectories", "dusk"),
    cfg_probe("cfg-light-flicker", "flicker deeper than 100 %",
              "light:\n  conditions: {flicker100: {flicker_depth: 1.5}}\n",
              "light.conditions.flicker100.flicker_depth"),
    cfg_probe("cfg-colour-sim2real", "a colour sensor against a grey recording",
              "bench:\n  sim2real_variants: [color_davis346]\n", "bench.sim2real_variants", "color_davis346"),
    cfg_probe("cfg-minis-off", "no mini-trajectories, but the default render list",
              "trajectory:\n  mini_groups: 0\n", "render.trajectories", "mini00_medium"),
    cfg_probe("cfg-resolution-zero", "downscale factor 0 in the training schedule",
              "splat:\n  resolution_schedule: [[0, 0]]\n", "splat.resolution_schedule"),
    cfg_probe("cfg-budget", "Gaussian budget minimum above maximum",
              "splat:\n  budget_min: 5000\n  budget_max: 100\n", "splat.budget_min"),
    cfg_probe("cfg-ply-unset", "model_source ply without a file", "splat:\n  model_source: ply\n",
              "splat.ply_path"),
    cfg_probe("cfg-ply-missing", "a PLY path that does not exist",
              "splat:\n  model_source: ply\n  ply_path: /nonexistent/pc.ply\n", "splat.ply_path"),
    cfg_probe("cfg-theta-range", "threshold range upside down",
              "events:\n  theta_range: [0.5, 0.2]\n", "events.theta_range"),
    cfg_probe("cfg-k1-zero", "a zero DVS-Voltmeter gain", "events:\n  k1: 0\n", "events.k1"),
    cfg_probe("cfg-real-events", "a real recording that is not there",
              "metrics:\n  real_events: nope.aedat4\n", "metrics.real_events", "nope.aedat4"),
    Probe("cfg-sensor-huge", "a custom sensor of 200000x200000 pixels",
          lambda t: ["config", "--validate", _yaml(t, "events:\n  sensor: custom\n  sensor_file: {}\n".format(
              _write(t / "huge.yaml", "width: 200000\nheight: 200000\n")))],
          ("events.sensor_file", "huge.yaml", "200000x200000"), None),
    Probe("render-sensor-huge", "gs2e render --sensor-size 200000x200000",
          lambda t: ["render", "--model", t, "--trajectory", t / "x.npz", "--out", t / "out",
                     "--sensor-size", "200000x200000"], ("--sensor-size", "200000x200000")),
    cfg_probe("cfg-yaml", "broken YAML", "render: [fps: 30\n", "config.yaml", "not valid YAML"),
    cfg_probe("cfg-list", "a list instead of a mapping", "- 1\n- 2\n", "expected a mapping"),
    Probe("cfg-missing-file", "a config file that does not exist",
          lambda t: ["config", "--validate", t / "nope.yaml"], ("nope.yaml",), None),
    Probe("cfg-scenes-missing", "a scenes table that does not exist",
          lambda t: ["config", "--validate", _yaml(t, f"scenes: {t / 'nope.tsv'}\n")],
          ("nope.tsv",), None),
    Probe("cfg-override-fps", "raising render.fps for one scene, forgetting the exposure",
          lambda t: ["config", "--validate", _yaml(t, "scenes: {}\n".format(_write(
              t / "s.tsv", "scene_id\tlayout\tpath\toverrides\nfast\tdemo\t\trender.fps=100\n")))],
          ("scene 'fast'", "render.exposure_us"), None),
    Probe("cfg-override-nan", "NaN in a scene override",
          lambda t: ["config", "--validate", _yaml(t, "scenes: {}\n".format(_write(
              t / "s.tsv", "scene_id\tlayout\tpath\toverrides\nx\tdemo\t\tevents.theta_on=.nan\n")))],
          ("scene 'x'", "events.theta_on"), None),
    Probe("cfg-layout", "a misspelt layout in the scenes table",
          lambda t: ["config", "--validate", _yaml(t, "scenes: {}\n".format(_write(
              t / "s.tsv", "scene_id\tlayout\tpath\toverrides\nx\tcolmapp\t/data/x\t\n")))],
          ("s.tsv:2", "layout"), None),
    # ---- a stage's own config (what the workflow passes, or --set by hand)
    Probe("json-nan", "NaN in --config-json",
          lambda t: ["events", _frames(t), "--fps", "100", "-o", t / "out",
                     "--config-json", '{"theta_on": NaN}'], ("events.theta_on",)),
    Probe("set-enum", "a misspelt model name with --set",
          lambda t: ["events", _frames(t), "--fps", "100", "-o", t / "out", "--set", "model=idea"],
          ("events.model", "idea")),
    Probe("set-syntax", "--set without '='",
          lambda t: ["events", _frames(t), "--fps", "100", "-o", t / "out", "--set", "model"],
          ("--set 'model'",)),
    Probe("render-exposure", "gs2e render with fps 100 and the default exposure",
          lambda t: ["render", "--model", _model(t), "--trajectory", _trajectory(t), "--out",
                     t / "out", "--config-json", '{"fps": 100}'], ("render.exposure_us",)),
    Probe("argparse-choice", "an unknown layout on the command line",
          lambda t: ["ingest", "--layout", "colmapp", "--src", t, "--out", t / "out"],
          ("invalid choice", "colmapp")),
    Probe("argparse-missing", "forgetting a required option",
          lambda t: ["events", _frames(t), "--fps", "100"], ("-o/--out",)),
    # ---- ingestion
    Probe("ingest-missing", "a source folder that does not exist",
          lambda t: ["ingest", "--layout", "folder", "--src", t / "nope", "--out", t / "out"],
          ("nope",)),
    Probe("ingest-empty", "an empty folder",
          lambda t: ["ingest", "--layout", "folder", "--src", (t / "empty").mkdir() or t / "empty",
                     "--out", t / "out"], ("empty", "no image files")),
    Probe("ingest-corrupt", "a text file named .png",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _write(_frames(t) / "f001.png", "not an image").parent, "--out", t / "out"],
          ("f001.png", "corrupt")),
    Probe("ingest-zero-bytes", "a 0-byte image (interrupted copy)",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _write(_frames(t) / "f002.png", b"").parent, "--out", t / "out"],
          ("f002.png", "empty")),
    Probe("ingest-truncated", "a truncated PNG",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _truncate(_frames(t, size=(64, 48)) / "f001.png", 0.3).parent,
                     "--out", t / "out"], ("f001.png",)),
    Probe("ingest-one-view", "a folder with a single photo",
          lambda t: ["ingest", "--layout", "folder", "--src", _frames(t, n=1), "--out", t / "out"],
          ("1 usable view",)),
    Probe("ingest-mixed", "photos of two sizes",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _frames(_frames(t, n=2).parent, names=["z.png"], size=(20, 12), values=[9]),
                     "--out", t / "out"], ("mixed resolutions", "z.png")),
    Probe("ingest-huge-image", "a PNG whose header declares 100000x100000 pixels",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _huge_png(_frames(t, n=2) / "z.png"), "--out", t / "out"],
          ("z.png", "100000x100000", "beyond")),
    Probe("ingest-duplicate", "the same photo twice",
          lambda t: ["ingest", "--layout", "folder", "--src",
                     _frames(t, names=["a.png", "b.png", "c.png"], values=[5, 5, 9]),
                     "--out", t / "out"], ("duplicate views", "a.png", "b.png")),
    Probe("ingest-out-in-src", "writing the output inside the source",
          lambda t: ["ingest", "--layout", "folder", "--src", _frames(t), "--out",
                     t / "frames" / "out"], ("must not be the source",), "frames/out"),
    Probe("ingest-colmap-no-model", "a COLMAP layout without sparse/",
          lambda t: ["ingest", "--layout", "colmap", "--src", _frames(t, folder="c/images").parent,
                     "--out", t / "out"], ("sparse",)),
    Probe("ingest-nerf-json", "a broken transforms.json",
          lambda t: ["ingest", "--layout", "nerf", "--src",
                     _write(t / "n" / "transforms.json", '{"frames": [').parent, "--out", t / "out"],
          ("transforms.json",)),
    Probe("ingest-scene-json", "a truncated scene.json",
          lambda t: ["ingest", "--layout", "internal", "--src",
                     _truncate(_scene(t) / "scene.json").parent, "--out", t / "out"],
          ("scene.json",)),
    # ---- sfm, training, trajectories
    Probe("sfm-no-scene", "SfM on a folder that is not a scene",
          lambda t: ["sfm", "--scene", _frames(t), "--out", t / "out"], ("scene.json",)),
    Probe("train-no-points", "training on a scene without points3d.npz",
          lambda t: ["train", "--scene", _scene(t, points=0), "--out", t / "out",
                     "--config-json", '{"sh_degree": 0, "budget": 100}'], ("points3d.npz",)),
    Probe("train-corrupt-points", "a truncated points3d.npz",
          lambda t: ["train", "--scene", _truncate(_scene(t) / "points3d.npz").parent,
                     "--out", t / "out"], ("points3d.npz",)),
    Probe("train-out-under-file", "an output path below a file",
          lambda t: ["train", "--scene", _scene(t), "--out", _write(t / "afile", "x") / "model"],
          ("afile", "not a folder"), None),
    Probe("train-out-unwritable", "an output folder that cannot be written",
          lambda t: ["train", "--scene", _scene(t), "--out", "/sys/gs2e-out/model"],
          ("/sys", "cannot write"), None),
    Probe("train-ckpt-unwritable", "a checkpoint folder that cannot be written",
          lambda t: ["train", "--scene", _scene(t), "--out", t / "out", "--checkpoint-dir",
                     "/sys/gs2e-ckpt"], ("--checkpoint-dir", "/sys")),
    Probe("trajectory-no-poses", "trajectories of a scene without poses",
          lambda t: ["trajectory", "--scene", _scene(t, poses=False), "--out", t / "out"],
          ("without poses",)),
    Probe("trajectory-nan-pose", "a NaN in a pose",
          lambda t: ["trajectory", "--scene", _nan_pose(_scene(t)), "--out", t / "out"],
          ("001.png", "NaN")),
    # ---- rendering
    Probe("render-truncated-trajectory", "a truncated trajectory file",
          lambda t: ["render", "--model", _model(t), "--trajectory", _truncate(_trajectory(t)),
                     "--out", t / "out"], ("straight.npz", "truncated")),
    Probe("render-foreign-npz", "an npz that is not a trajectory",
          lambda t: ["render", "--model", _model(t), "--trajectory",
                     (np.savez(t / "x.npz", a=np.zeros(3)), t / "x.npz")[1], "--out", t / "out"],
          ("x.npz",)),
    Probe("render-no-model", "a model folder without model.json",
          lambda t: ["render", "--model", t, "--trajectory", _trajectory(t), "--out", t / "out"],
          ("model.json",)),
    Probe("render-empty-model", "a Gaussian model with no Gaussians",
          lambda t: ["render", "--model", _empty_ply(t), "--trajectory", _trajectory(t),
                     "--out", t / "out"], ("pc.ply", "no Gaussians")),
    Probe("render-truncated-ply", "a truncated point_cloud.ply",
          lambda t: ["render", "--model", _truncate(_model(t) / "pc.ply").parent, "--trajectory",
                     _trajectory(t), "--out", t / "out"], ("pc.ply",)),
    # ---- events from frames
    Probe("events-ts-count", "fewer timestamps than frames",
          lambda t: ["events", _frames(t), "--timestamps", _write(t / "t.txt", "0\n1000\n"),
                     "-o", t / "out"], ("t.txt", "2 timestamps")),
    Probe("events-ts-order", "timestamps that go backwards",
          lambda t: ["events", _frames(t), "--timestamps", _write(t / "t.txt", "0\n2000\n1000\n3000\n"),
                     "-o", t / "out"], ("t.txt", "increase strictly")),
    Probe("events-ts-nan", "NaN in the timestamps file",
          lambda t: ["events", _frames(t), "--timestamps", _write(t / "t.txt", "0\nnan\n2\n3\n"),
                     "-o", t / "out"], ("t.txt", "NaN")),
    Probe("events-ts-text", "a CSV header in the timestamps file",
          lambda t: ["events", _frames(t), "--timestamps", _write(t / "t.txt", "t_us\n0\n1\n2\n3\n"),
                     "-o", t / "out"], ("t.txt",)),
    Probe("events-no-rate", "frames without timestamps or --fps",
          lambda t: ["events", _frames(t), "-o", t / "out"], ("--fps",)),
    Probe("events-cfa-frames", "a colour filter on frame files (luminance)",
          lambda t: ["events", _frames(t), "--fps", "30", "--set", "sensor=color_davis346", "-o", t / "out"],
          ("events.cfa", "--model")),
    Probe("events-no-images", "a folder with no images",
          lambda t: ["events", _write(t / "d" / "notes.txt", "x").parent, "--fps", "30",
                     "-o", t / "out"], ("no images",)),
    Probe("events-sizes", "frames of different sizes",
          lambda t: ["events", _frames(_frames(t, n=3).parent, names=["f009.png"], size=(8, 8),
                                       values=[1]), "--fps", "30", "-o", t / "out"],
          ("f009.png", "shape")),
    Probe("events-video", "a corrupt video file",
          lambda t: ["events", _write(t / "clip.mp4", b"\0" * 100), "-o", t / "out"], ("clip.mp4",)),
    Probe("events-npz", "an npz without a 'frames' array",
          lambda t: ["events", (np.savez(t / "a.npz", x=np.zeros((2, 4, 4))), t / "a.npz")[1],
                     "--fps", "10", "-o", t / "out"], ("a.npz", "frames")),
    Probe("events-out-under-file", "an output path below a file",
          lambda t: ["events", _frames(t), "--fps", "30", "-o", _write(t / "afile", "x") / "ev"],
          ("afile", "not a folder"), None),
    Probe("events-stats-corrupt", "event statistics of a corrupt .h5",
          lambda t: ["events-stats", _write(t / "ev.h5", b"\x89HDF\r\n\x1a\n" + b"\0" * 64)],
          ("ev.h5",), None),
    Probe("events-stats-columns", "a text event file with 3 columns",
          lambda t: ["events-stats", _write(t / "ev.txt", "1 2 3\n4 5 6\n")], ("ev.txt",), None),
    Probe("events-stats-raw", "a Prophesee .raw whose header gives no version",
          lambda t: ["events-stats", _write(t / "ev.raw", "% geometry 640x480\n" + "\0" * 8)],
          ("ev.raw", "no version"), None),
    Probe("events-stats-preset-empty", "a sensor preset from a recording with no events",
          lambda t: ["events-stats", _empty_recording(t / "ev.aedat4"), "--write-preset", t / "p.yaml"],
          ("ev.aedat4", "too few events"), "p.yaml"),
    Probe("events-convert-suffix", "converting to a container gs2e does not write",
          lambda t: ["events-convert", _write(t / "ev.txt", "1 2 3 1\n"), t / "out.evt3"],
          ("out.evt3", "unknown output container"), "out.evt3"),
    Probe("events-convert-no-size", "text events to AEDAT4 without a sensor size",
          lambda t: ["events-convert", _write(t / "ev.txt", "1 2 3 1\n"), t / "out.aedat4"],
          ("ev.txt", "--width"), "out.aedat4"),
    Probe("events-convert-size", "a 4000x3000 recording to EVT2 (at most 2048x2048)",
          lambda t: ["events-convert", _write(t / "ev.txt", "1 2 3 1\n"), t / "out.raw",
                     "--width", "4000", "--height", "3000"], ("out.raw", "2048x2048"), "out.raw"),
    Probe("events-convert-corrupt", "converting a DAT file whose header has no version line",
          lambda t: ["events-convert", _write(t / "ev.dat", b"% Width 64\n% Height 48\n\x0c"),
                     t / "out.h5"], ("ev.dat",), "out.h5"),
    # ---- tables, report, clean
    Probe("summary-corrupt", "a corrupt scene table in the summary",
          lambda t: ["summary", _write(t / "m.parquet", b"PAR1 not really"), "--out",
                     t / "out.parquet"], ("m.parquet",), "out.parquet"),
    Probe("metrics-corrupt", "a truncated stage metrics table",
          lambda t: ["metrics", "--scene-dir", _write(t / "s" / "sfm" / "metrics.parquet", b"PAR1x").parents[1],
                     "--scene-id", "s", "--out", t / "out.parquet"], ("metrics.parquet",), "out.parquet"),
    Probe("report-corrupt-curve", "a truncated training curve in the results",
          lambda t: ["report", "--results-dir", _write(t / "r" / "s" / "splat" / "curve.parquet",
                                                      b"PAR1x").parents[2],
                     "--scenes", "s", "--no-real-events", "--out", t / "out.html"],
          ("curve.parquet",), "out.html"),
    # ---- a dataset of many scenes (gs2e.dataset)
    cfg_probe("cfg-gate-fraction", "a share of registered views above 1",
              "dataset:\n  min_registered_fraction: 80\n", "dataset.min_registered_fraction"),
    Probe("gate-no-events", "gating a scene whose events were never simulated",
          lambda t: ["gate", "--scene-dir", _gate_scene(t), "--scene-id", "s", "--runs", "base_mild",
                     "--out", t / "out.json"], ("events/base_mild/stats.json",), "out.json"),
    Probe("gate-fails", "a scene below its quality gates",
          lambda t: ["gate", "--scene-dir", _gate_scene(t), "--scene-id", "s", "--out", t / "out.json",
                     "--config-json", '{"min_test_psnr_db": 30}'],
          ("scene 's' fails its quality gates", "held-out PSNR 12.50 dB < 30.00 dB"), "out.json"),
    Probe("dataset-bad-config", "a dataset run with a misspelt key in its config",
          lambda t: ["dataset", "--configfile", _yaml(t, "scenes: x.tsv\nrender:\n  fsp: 30\n")],
          ("render.fsp",), None),
    Probe("dataset-directory", "a dataset run pointed at another folder with Snakemake's --directory",
          lambda t: ["dataset", "--configfile", _yaml(t, "scenes: x.tsv\n"), "--", "--directory", t],
          ("--directory",), None),
    Probe("datasheet-no-summary", "a datasheet before the summary exists",
          lambda t: ["datasheet", "--summary", t / "summary.parquet", "--scenes-table",
                     _write(t / "scenes.tsv", "scene_id\tlayout\tpath\toverrides\ndemo\tdemo\t\t\n"),
                     "--out", t / "out.md"], ("summary.parquet",), "out.md"),
    Probe("datasheet-bad-scenes-json", "a datasheet given scenes that are not a list of rows",
          lambda t: ["datasheet", "--summary", t / "summary.parquet", "--scenes-json", '{"demo": "demo"}',
                     "--out", t / "out.md"], ("--scenes-json", "scene_id"), "out.md"),
    Probe("clean-missing", "cleaning a results folder that does not exist",
          lambda t: ["clean", t / "nope"], ("nope", "no such folder"), None),
]


@pytest.mark.parametrize("probe", PROBES, ids=[p.id for p in PROBES])
def test_bad_input_fails_early_and_clearly(probe, tmp_path):
    argv = probe.make(tmp_path)
    rc, _, err = gs2e(*argv)
    lines = error_lines(err)
    assert rc == 2, f"exit {rc}, stderr:\n{err[-3000:]}"
    assert "Traceback" not in err, err
    assert len(lines) == 1 and err.rstrip().endswith(lines[0]), err[-3000:]
    for needle in probe.needles:
        assert needle in lines[0], f"{needle!r} not in {lines[0]!r}"
    if probe.out:
        out = tmp_path / probe.out
        assert not out.exists(), f"partial output {out}"
        assert not temporaries(out.parent), temporaries(out.parent)


def test_probe_ids_are_unique():
    assert len({p.id for p in PROBES}) == len(PROBES)


# ---------------------------------------------------------------- full disk, signals
def _subprocess_gs2e(argv, fsize_bytes: int | None = None, **kw):
    import resource
    import subprocess

    def limit():
        if fsize_bytes is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize_bytes, fsize_bytes))

    env = {**os.environ, "GS2E_PROGRESS": "0", "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    return subprocess.Popen([sys.executable, "-m", "gs2e", *map(str, argv)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=limit, **kw)


# events: the subprocess compiles its numba kernels anew (no cache can be
# written under the file-size limit): minutes on 2 cores
@pytest.mark.parametrize("stage", [pytest.param("events", marks=pytest.mark.slow), "ingest"])
def test_full_disk_is_one_line_and_leaves_nothing(stage, tmp_path):
    """A disk that fills up mid-write (simulated with the file-size limit, which
    fails writes with EFBIG as a full disk fails them with ENOSPC)."""
    if stage == "events":
        # every pixel brightens by ~0.1 log units per frame: ~330k events, 4 MB
        frames = _frames(tmp_path, n=40, size=(64, 48), values=list(np.linspace(10, 250, 40).astype(int)))
        argv = ["events", frames, "--fps", "1000", "-o", tmp_path / "out", "--set", "model=ideal",
                "--set", "theta_on=0.05", "--set", "theta_off=0.05", "--set", "compression=none",
                "--set", "preview=false"]
        # compile the kernels first (in this process): numba cannot write its
        # cache under the limit, and compiling takes long
        assert gs2e(*argv, "-o", tmp_path / "warm")[0] == 0  # the last -o wins
    else:  # noise images: PNGs of ~37 kB each
        frames = tmp_path / "noise"
        rng = np.random.default_rng(0)
        for i in range(4):
            write_rgb(frames / f"{i}.png", rng.integers(0, 256, (96, 128, 3), dtype=np.uint8))
        argv = ["ingest", "--layout", "folder", "--src", frames, "--out", tmp_path / "out"]
    proc = _subprocess_gs2e(argv, fsize_bytes=20_000)
    _, err = proc.communicate(timeout=600)
    lines = error_lines(err)
    # 2, not a crash: HDF5 used to segfault in teardown after a failed write (139)
    assert proc.returncode == 2, err[-3000:]
    assert "Traceback" not in err and len(lines) == 1, err[-3000:]
    assert "File too large" in lines[0] and str(tmp_path) in lines[0], lines[0]  # names the file
    assert not (tmp_path / "out").exists() and not temporaries(tmp_path)


def test_sigterm_cleans_up_like_an_exception(tmp_path):
    """SIGTERM (Slurm's time limit, scancel, kill) mid-simulation: exit 143, one
    line, no output and no temporary left."""
    import signal
    import time

    frames = _frames(tmp_path, n=400, size=(64, 48), values=list(np.resize(np.arange(20, 220), 400)))
    proc = _subprocess_gs2e(["events", frames, "--fps", "1000", "-o", tmp_path / "out",
                             "--set", "preview=false", "--set", "batch_frames=4"])
    deadline = time.time() + 1800  # a cold start compiles the simulator first
    while not any(p.name.startswith(".out.tmp-") for p in tmp_path.iterdir()):
        assert proc.poll() is None and time.time() < deadline, "no temporary appeared"
        time.sleep(0.01)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, err[-3000:]
    lines = error_lines(err)
    assert len(lines) == 1 and "terminated by SIGTERM" in lines[0] and "Traceback" not in err, err
    assert not (tmp_path / "out").exists() and not temporaries(tmp_path)


# ---------------------------------------------------------------- valid unusual inputs
def _stats(out: Path) -> tuple[dict, dict]:
    import pandas as pd

    js = json.loads((out / "stats.json").read_text())["stats"]  # strict JSON: no NaN tokens
    row = pd.read_parquet(out / "stats.parquet").iloc[0].to_dict()
    return js, row


NULL_STATS = ("rate_meps", "on_fraction", "iei_median_ms", "iei_mean_ms", "iei_p10_ms", "iei_p90_ms",
              "density_median_active_hz")


@pytest.mark.parametrize("case", ["constant", "one-frame", "black"])
def test_no_events_is_a_valid_dataset_with_null_statistics(case, tmp_path):
    n, values = {"constant": (6, [128] * 6), "one-frame": (1, [128]), "black": (5, [0] * 5)}[case]
    frames = _frames(tmp_path, n=n, values=values)
    for model in ("ideal", "voltmeter"):
        out = tmp_path / f"out_{model}"
        rc, _, err = gs2e("events", frames, "--fps", "100", "-o", out, "--set", f"model={model}",
                          "--set", "k4=0", "--set", "k5=0")
        assert rc == 0, err[-3000:]
        js, row = _stats(out)
        assert js["n_events"] == row["n_events"] == 0 and js["n_frames"] == n
        for k in NULL_STATS:
            if case == "one-frame" or k != "rate_meps":
                assert js[k] is None and row[k] is None, (k, js[k], row[k])
        assert js["n_iei"] == 0
        rc, text, err = gs2e("events-stats", out / "events.h5")
        assert rc == 0 and json.loads(text)["stats"]["iei_median_ms"] is None, err


def test_events_with_no_intervals_have_null_interval_statistics(tmp_path):
    """Two frames: each pixel fires at most once per threshold crossing, all in
    one interval, so there are events but no per-pixel inter-event interval at
    theta larger than half the change."""
    # sRGB 60 -> 90 is a log change of ~0.81 in linear luminance: one crossing of 0.5
    frames = _frames(tmp_path, n=2, values=[60, 90])
    rc, _, err = gs2e("events", frames, "--fps", "100", "-o", tmp_path / "out", "--set", "model=ideal",
                      "--set", "theta_on=0.5", "--set", "theta_off=0.5")
    assert rc == 0, err[-3000:]
    js, row = _stats(tmp_path / "out")
    assert js["n_events"] > 0 and js["n_iei"] == 0
    assert js["iei_median_ms"] is None and row["iei_median_ms"] is None
    assert js["on_fraction"] == 1.0


def test_negative_timestamps_shift_the_stream(tmp_path):
    """Timestamps before 0 (a recording's own clock) are valid: the same events
    as the shifted sequence, shifted, with the same statistics."""
    from gs2e.events.io import read_h5

    vals = [40, 80, 40, 80, 40, 80]
    frames = _frames(tmp_path, n=6, values=vals)
    runs = {}
    for name, t0 in (("pos", 0), ("neg", -5000)):
        ts = _write(tmp_path / f"{name}.txt", "\n".join(str(t0 + 1000 * i) for i in range(6)))
        rc, _, err = gs2e("events", frames, "--timestamps", ts, "-o", tmp_path / name,
                          "--set", "model=ideal", "--set", "theta_on=0.2", "--set", "theta_off=0.2")
        assert rc == 0, err[-3000:]
        runs[name] = (read_h5(tmp_path / name / "events.h5"), _stats(tmp_path / name)[0])
    (ev_p, at_p), st_p = runs["pos"]
    (ev_n, at_n), st_n = runs["neg"]
    assert len(ev_p) > 0 and np.array_equal(ev_n.t, ev_p.t - 5000)
    assert at_n["t_offset"] == -5000 and np.array_equal(ev_n.x, ev_p.x)
    for k in ("n_events", "n_iei", "iei_median_ms", "on_fraction", "duration_s"):
        assert st_n[k] == st_p[k] and st_p[k] is not None, k


def test_frames_play_in_natural_order(tmp_path):
    """frame1 .. frame12 (no zero padding) play 1, 2, .. 12, not 1, 10, 11, 12, 2:
    brightness rises with the number, so every event is ON."""
    names = [f"frame{i}.png" for i in range(1, 13)]
    frames = _frames(tmp_path, names=names, values=[20 + 15 * i for i in range(12)])
    rc, _, err = gs2e("events", frames, "--fps", "100", "-o", tmp_path / "out",
                      "--set", "model=ideal", "--set", "theta_on=0.1", "--set", "theta_off=0.1")
    assert rc == 0, err[-3000:]
    js, _ = _stats(tmp_path / "out")
    assert js["n_events"] > 0 and js["on_fraction"] == 1.0
    # hidden files (macOS '._frame3.png', a killed job's temporaries) are not frames
    _write(frames / "._frame3.png", b"\0\0")
    rc, _, err = gs2e("events", frames, "--fps", "100", "-o", tmp_path / "out2", "--set", "model=ideal")
    assert rc == 0, err[-3000:]


def test_ingest_and_training_split_use_the_same_natural_order(tmp_path):
    from gs2e.io.images import list_images
    from gs2e.splat.views import split_views

    names = [f"img{i}.png" for i in (1, 2, 10, 11, 3)]
    d = _frames(tmp_path, names=names, values=[10, 20, 30, 40, 50])
    assert [p.name for p in list_images(d)] == ["img1.png", "img2.png", "img3.png", "img10.png", "img11.png"]

    class V:
        def __init__(self, name):
            self.name = name

    train, test = split_views([V(n) for n in names], test_every=2)
    assert [v.name for v in test] == ["img1.png", "img3.png", "img11.png"]


# ---------------------------------------------------------------- the docs table
def probe_table() -> str:
    """Markdown table: every probe and the line a user sees (paths shortened)."""
    import tempfile

    rows = ["| probe | what the user did | what the user sees (exit 2) |", "|---|---|---|"]
    for p in PROBES:
        with tempfile.TemporaryDirectory() as d:
            rc, _, err = gs2e(*p.make(Path(d)))
            lines = error_lines(err)
            msg = lines[0] if lines else f"(exit {rc}) " + " ".join(err.split())[-200:]
            msg = msg.replace(str(Path(d).resolve()), "…").replace(d, "…")
            msg = re.sub(r"\.tmp-[\w.@-]+", ".tmp-…", msg)
        rows.append(f"| `{p.id}` | {p.what} | `{msg.replace('|', '/')}` |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    os.environ.setdefault("GS2E_PROGRESS", "0")
    sys.stdout.write(probe_table())
