"""Fine-tuning PIE-Net-Lite on gs2e data (gs2e.bench.finetune) and the real
recordings it is scored on (gs2e.events.recordings): training lowers the loss
on real simulated events, the same bytes at any thread count, hard inputs
(one frame, no events, frames smaller than the crop), and bad inputs failing
early with the file or key named."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from gs2e.events.settings import event_settings
from gs2e.bench.finetune import (FinetuneSettings, Sequence, evaluate, finetune, load_network,
                                 recording_sequence)
from gs2e.common.errors import ConfigError, InputError
from tests.conftest import run_cli, shared_data


def _sliding(H: int = 48, W: int = 64, frames: int = 8, px_per_frame: float = 0.5, row0: int = 20) -> Sequence:
    """A photograph sliding sideways, its events from gs2e's ideal simulator
    (10 samples per frame): the training and test data of these tests."""
    from skimage import data

    from gs2e.bench.learned import interval_inputs
    from gs2e.common.color import srgb_to_linear
    from gs2e.config import load_section
    from gs2e.events.models import make_model

    img = data.camera()[::4, ::4] / 255.0  # 128 x 128, sRGB

    def frame(dx: float) -> np.ndarray:
        i, f = int(np.floor(10 + dx)), 10 + dx - np.floor(10 + dx)
        return (1 - f) * img[row0:row0 + H, i:i + W] + f * img[row0:row0 + H, i + 1:i + 1 + W]

    sub = 10
    ts = np.arange(frames * sub + 1, dtype=np.int64) * 500
    lin = np.stack([srgb_to_linear(frame(px_per_frame / sub * k)) for k in range(len(ts))]).astype(np.float32)
    cfg = {**load_section("events"), "model": "ideal", "theta_on": 0.2, "theta_off": 0.2}
    ev = make_model(event_settings(cfg), (H, W), 0)[0].simulate(ts, lin)
    targets = np.stack([frame(px_per_frame * k) for k in range(1, frames + 1)]).astype(np.float32)
    return Sequence(f"sliding@{row0}", np.stack(list(interval_inputs(ev, (H, W), ts[::sub]))), targets)


SMALL = FinetuneSettings(steps=2, batch=2, seq_frames=3, crop_px=32, lr=1e-3, seed=3)


def _l1(model, q: Sequence) -> float:
    """Mean L1 to the targets after EVREAL's normalisation (the scored image)."""
    from gs2e.bench.learned import robust_normalize, run_network

    return float(np.mean([np.abs(robust_normalize(o) - t).mean()
                          for o, t in zip(run_network(model, q.inputs), q.targets)]))


def test_training_lowers_the_loss_on_simulated_events():
    """Twelve steps on one sliding photograph lower the L1 distance of the
    network's normalised output to the sharp frames, on that sequence and on
    another part of the photo."""
    train, other = _sliding(row0=20), _sliding(row0=60)
    model = load_network("pienet_lite")
    before = _l1(model, train), _l1(model, other)
    rows = finetune(model, [train], FinetuneSettings(steps=12, batch=2, seq_frames=4, crop_px=40, lr=1e-3))
    after = _l1(model, train), _l1(model, other)
    assert [r["step"] for r in rows] == list(range(1, 13))
    assert all(np.isfinite(r["loss"]) and r["cpu_s"] > 0 for r in rows)
    assert after[0] < 0.75 * before[0] and after[1] < 0.9 * before[1], (before, after)


def test_the_shipped_network_stays_shipped():
    from gs2e.bench.learned import load

    shipped = {k: v.clone() for k, v in load("pienet_lite").state_dict().items()}
    model = load_network("pienet_lite")
    finetune(model, [_sliding()], SMALL)
    assert any(not torch.equal(v, model.state_dict()[k]) for k, v in shipped.items())
    assert all(torch.equal(v, load("pienet_lite").state_dict()[k]) for k, v in shipped.items())


def _weights(settings: FinetuneSettings, seqs) -> dict:
    model = load_network("pienet_lite")
    finetune(model, seqs, settings)
    return {k: v.numpy().tobytes() for k, v in model.state_dict().items()}


def test_same_bytes_whatever_the_thread_count_and_the_seed_matters():
    seqs = [_sliding()]
    before = torch.get_num_threads()
    try:
        out = {}
        for threads in (2, 1):
            torch.set_num_threads(threads)
            out[threads] = _weights(SMALL, seqs)
            assert torch.get_num_threads() == threads  # restored
    finally:
        torch.set_num_threads(before)
    assert out[1] == out[2]
    other = _weights(FinetuneSettings(**{**SMALL.__dict__, "seed": 4}), seqs)
    assert other != out[1]


def test_hard_inputs_one_interval_no_events_smaller_than_the_crop():
    """A one-interval sequence without events, 20 x 24 px (below the 32 px
    crop): training runs (crop and sequence length shrink to fit) and the
    scores are finite."""
    q = Sequence("flat", np.zeros((1, 5, 20, 24), np.float32), np.full((1, 20, 24), 0.4, np.float32))
    model = load_network("pienet_lite")
    rows = finetune(model, [q], SMALL)
    assert len(rows) == 2 and all(np.isfinite(r["loss"]) for r in rows)
    scores = evaluate(model, [q], "finetuned")
    assert len(scores) == 1 and scores[0]["frame"] == 1 and np.isfinite(scores[0]["mse"])


def test_bad_settings_and_sequences_name_the_key():
    with pytest.raises(ConfigError, match="crop_px"):
        FinetuneSettings(crop_px=0)
    with pytest.raises(ConfigError, match="variant"):
        FinetuneSettings(variant="e2vid")
    with pytest.raises(ConfigError, match="lr"):
        FinetuneSettings(lr=float("nan"))
    with pytest.raises(InputError, match="q: inputs"):
        Sequence("q", np.zeros((2, 5, 8, 8), np.float32), np.zeros((3, 8, 8), np.float32))
    with pytest.raises(InputError, match="no training sequences"):
        finetune(load_network("pienet_lite"), [], SMALL)


# ------------------------------------------------------------------ real recordings
def test_slider_depth_reads_as_its_sources_say():
    from gs2e.events.recordings import read_recording

    rec = read_recording(shared_data("slider_depth"))
    assert rec.shape == (180, 240) and len(rec.events) == 50_000
    assert len(rec.t_us) == len(rec.frames) == 5 and rec.t_us[-1] <= rec.events.t[-1]
    assert rec.frames.min() >= 0 and rec.frames.max() <= 1 and rec.frames.std() > 0.05
    q = recording_sequence(rec)
    assert q.inputs.shape == (4, 5, 180, 240) and q.targets.shape == (4, 180, 240)
    inside = (rec.events.t > rec.t_us[0]) & (rec.events.t <= rec.t_us[-1])
    # every event between the first and last frame is in one voxel grid: its
    # polarity (+1 ON, -1 OFF) spread over the bins
    net = (2.0 * rec.events.p[inside].astype(np.float64) - 1.0).sum()
    assert q.inputs.astype(np.float64).sum() == pytest.approx(net, abs=1e-2)
    assert q.inputs[0].any() and q.inputs[-1].any()


def test_a_recording_without_frames_or_files_fails_naming_it(tmp_path):
    from gs2e.events.recordings import read_recording

    with pytest.raises(InputError, match=r"dvxplorer_sample.aedat4: 0 APS frames"):
        read_recording(shared_data("events", "dvxplorer_sample.aedat4"))
    with pytest.raises(InputError, match=r"events.txt does not exist"):
        read_recording(tmp_path)
    with pytest.raises(InputError, match="not an ECD sequence folder"):
        read_recording(tmp_path / "nothing.h5")


def test_cli_bad_inputs_fail_before_training_and_leave_nothing(tmp_path):
    out = tmp_path / "ft"
    proc = run_cli("bench-finetune", "--root", str(tmp_path), "--train", "a", "--eval", "a,b", "--out", str(out))
    assert proc.returncode != 0 and "--eval: ['a'] also in --train" in proc.stderr
    proc = run_cli("bench-finetune", "--root", str(tmp_path), "--train", "a", "--out", str(out))
    assert proc.returncode != 0 and "no windows tables for the scene(s) ['a']" in proc.stderr
    proc = run_cli("bench-finetune", "--root", str(tmp_path / "none"), "--train", "a", "--out", str(out))
    assert proc.returncode != 0 and "none: no such results folder" in proc.stderr
    proc = run_cli("bench-finetune", "--root", str(tmp_path), "--train", "a", "--steps", "-1", "--out", str(out))
    assert proc.returncode != 0 and "steps must be a non-negative integer" in proc.stderr
    assert not out.exists() and not list(tmp_path.glob(".ft*"))


def test_cli_on_a_pipeline_run_and_a_real_recording(tiny_pipeline, tmp_path):
    """End to end through gs2e.data: the tiny pipeline's trajectory with
    events over its whole span (the export tests' tree), two steps, scored on
    slider_depth; the weights load back into a fresh network."""
    from pie_net import load_model

    import pandas as pd
    from tests.test_export_formats import export_tree

    tree = export_tree(tiny_pipeline, tmp_path)
    out = tmp_path / "ft"
    run_cli("bench-finetune", "--root", str(tree.parent), "--train", tree.name, "--real",
            str(shared_data("slider_depth")), "--out", str(out), "--steps", "2", "--crop-px", "32",
            check=True)
    scores = pd.read_parquet(out / "scores.parquet")
    assert sorted(set(scores["weights"])) == ["finetuned", "shipped"] and set(scores["data"]) == {"real"}
    assert len(scores) == 2 * 4 and np.isfinite(scores["psnr"]).all()
    run = json.loads((out / "run.json").read_text())
    assert run["train_intervals"] >= 2 and run["settings"]["steps"] == 2
    assert len(pd.read_parquet(out / "history.parquet")) == 2
    fresh = load_model(pretrained=False, device="cpu", variant="pie-net-lite")
    fresh.load_state_dict(torch.load(out / "weights.pt"))


def test_cli_help_states_the_settings_defaults():
    """The CLI's help names FinetuneSettings' defaults (not imported there: see
    gs2e.bench.cli), so a changed default must change the help too."""
    import re

    from dataclasses import fields

    help_text = " ".join(run_cli("bench-finetune", "--help", check=True).stdout.split())
    d = FinetuneSettings()
    for f in fields(d):
        m = re.search("--" + f.name.replace("_", "-") + r" \S+ [^(]*\(default ([^)]*)\)", help_text)
        assert m, f.name
        value = getattr(d, f.name)
        assert (m.group(1) == value if isinstance(value, str) else float(m.group(1)) == value), (f.name, m.group(0))


def test_robust_loss_is_the_scored_normalisation():
    """The differentiable normalisation equals the scorer's (numpy) one, and
    its gradient reaches the output."""
    from gs2e.bench.finetune import robust_normalize_t
    from gs2e.bench.learned import robust_normalize

    rng = np.random.default_rng(0)
    img = rng.random((2, 1, 30, 40)).astype(np.float32) * 0.5 + 0.2
    t = torch.tensor(img, requires_grad=True)
    out = robust_normalize_t(t)
    for b in range(2):
        np.testing.assert_allclose(out[b, 0].detach().numpy(), robust_normalize(img[b, 0]), atol=1e-5)
    out.sum().backward()
    assert torch.isfinite(t.grad).all() and t.grad.abs().sum() > 0
    flat = torch.full((1, 1, 8, 8), 0.3, requires_grad=True)  # no contrast: finite, no blow-up
    assert torch.isfinite(robust_normalize_t(flat)).all()


def test_make_finetune_data_plan_is_valid(tmp_path):
    """config/finetune.yaml (make finetune's data) passes the workflow's checks:
    every real capture plus the demo scene, the three base speeds each, sharp
    frames, events and windows only (no benchmark or export jobs), gated."""
    from gs2e.testing import run_snakemake
    from tests.conftest import REPO, planned_jobs

    shared_data("captures")
    proc = run_snakemake("-n", "--cores", "2", "--directory", str(REPO), "--configfile",
                         str(REPO / "config" / "config.yaml"), str(REPO / "config" / "finetune.yaml"),
                         "--config", f"results_dir={tmp_path / 'out'}", "--", "scenes")
    assert proc.returncode == 0, proc.stderr[-3000:]
    jobs = planned_jobs(proc.stdout)
    assert jobs["train"] == 16 and jobs["events"] == 48 and jobs["windows"] == 48
    assert jobs["model_gate"] == 16 and jobs["gate"] == 16
    assert "bench" not in jobs and "export" not in jobs
