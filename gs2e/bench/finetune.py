"""Fine-tuning a learned video reconstructor on gs2e data (``gs2e bench-finetune``).

The evidence the paper's title claims ("an effective data generator") is that
a model trained on the generated data gets better on data it has not seen.
This module fine-tunes PIE-Net-Lite (or PIE-Net, :mod:`gs2e.bench.learned`)
from its shipped weights on the trajectories of some scenes of a gs2e results
tree, read through :class:`gs2e.data.EventWindowDataset`, and scores it before
and after on the trajectories of other scenes and on real recordings with APS
frames (:mod:`gs2e.events.recordings`).

Training (E2VID's recipe, shortened; Rebecq et al., TPAMI 2019): each step takes
``batch`` sequences of ``seq_frames`` consecutive frame intervals, one random
crop of ``crop_px`` per sequence (the same for all its frames) and a random
horizontal flip, runs the network from a reset state through the sequence
and minimises, by Adam, the mean L1 distance between its output and the sharp
frame's grey (luminance, sRGB-encoded, in [0, 1]) at the end of each interval,
by default after EVREAL's robust normalisation of the output (``loss``
"robust": the scored image; a pilot on the demo's data, 40 steps, scored on a
held-out path: plain L1 lost 2.5 dB against the shipped weights, the
normalised L1 gained 1.4 dB at lr 1e-4 and 2.2 dB at 3e-4). PIE-Net detaches
its recurrent state after each step, so the gradient of an interval's loss
reaches that interval's computation only. E2VID also uses LPIPS, which needs
weights downloaded at run time: not used here.

Scoring is the video task's protocol for learned methods: from a reset state
at the first frame of a sequence, every later frame scored after EVREAL's
robust normalisation (:func:`gs2e.bench.learned.robust_normalize`), PSNR and
SSIM against the sharp frame's grey (gs2e) or the APS frame / 255 (real).

Everything runs on one torch thread: the same settings give the same weights
and scores, byte for byte, whatever the machine's thread count.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass
from typing import Callable, Iterable

import numpy as np

from gs2e.common.errors import ConfigError, InputError
from gs2e.events.models import Events


LOSSES = ("robust", "l1", "both")


def robust_normalize_t(img, q_lo: float = 0.01, q_hi: float = 0.99):
    """:func:`gs2e.bench.learned.robust_normalize` per image of a (B, 1, H, W)
    tensor, differentiable (the percentiles by torch.quantile's interpolation)."""
    import torch

    flat = img.flatten(1)
    lo = torch.quantile(flat, q_lo, dim=1)[:, None, None, None]
    hi = torch.quantile(flat, q_hi, dim=1)[:, None, None, None]
    return ((img - lo) / (hi - lo).clamp_min(1e-6)).clamp(0.0, 1.0)


def frame_loss(out, target, kind: str):
    """Mean L1 of one interval's (B, 1, h, w) output against its target:
    ``robust`` after EVREAL's normalisation of the output (the score's
    protocol: offset and scale are free, the shape of the image is not),
    ``l1`` as it is, ``both`` their sum."""
    a = (robust_normalize_t(out) - target).abs().mean() if kind in ("robust", "both") else 0.0
    b = (out - target).abs().mean() if kind in ("l1", "both") else 0.0
    return a + b


@dataclass(frozen=True)
class FinetuneSettings:
    """``steps`` optimiser steps of ``batch`` sequences of ``seq_frames``
    intervals, cropped to ``crop_px`` (px, square; smaller frames: their
    shorter side); Adam at ``lr``; ``seed`` fixes crops, flips and picks."""

    variant: str = "pienet_lite"
    steps: int = 200
    batch: int = 4
    seq_frames: int = 8
    crop_px: int = 128
    lr: float = 3e-4
    seed: int = 0
    loss: str = "robust"

    def __post_init__(self):
        from gs2e.bench.learned import VARIANTS

        if self.variant not in VARIANTS:
            raise ConfigError(f"variant must be one of {sorted(VARIANTS)}, got {self.variant!r}")
        for key in ("steps", "batch", "seq_frames", "crop_px"):
            v = getattr(self, key)
            if not (isinstance(v, int) and v >= (0 if key == "steps" else 1)):
                raise ConfigError(f"{key} must be a {'non-negative' if key == 'steps' else 'positive'} "
                                  f"integer, got {v!r}")
        if self.loss not in LOSSES:
            raise ConfigError(f"loss must be one of {LOSSES}, got {self.loss!r}")
        if not (self.lr > 0 and np.isfinite(self.lr)):
            raise ConfigError(f"lr must be a positive number, got {self.lr!r}")


@dataclass
class Sequence:
    """Consecutive frame intervals of one trajectory or recording:
    ``inputs`` (N, 5, H, W) float32, the network's input per interval;
    ``targets`` (N, H, W) float32 in [0, 1], the frame at each interval's end."""

    name: str
    inputs: np.ndarray
    targets: np.ndarray

    def __post_init__(self):
        if len(self.inputs) != len(self.targets) or self.inputs.shape[2:] != self.targets.shape[1:]:
            raise InputError(f"{self.name}: inputs {self.inputs.shape} do not match targets "
                             f"{self.targets.shape}")


def dataset_sequences(root, scenes: Iterable[str], trajectories: Iterable[str] | None = None) -> list[Sequence]:
    """The covered frame windows of ``scenes`` under the results folder
    ``root`` (through :class:`gs2e.data.EventWindowDataset`), one
    :class:`Sequence` per run of consecutive frames of a trajectory."""
    from gs2e.bench.dataset import grey
    from gs2e.bench.learned import network_input
    from gs2e.data import EventWindowDataset

    scenes = list(scenes)
    ds = EventWindowDataset(root, scenes=scenes, trajectories=trajectories, window="inter",
                            representation="raw", load=("rgb",))
    found = {tr.scene for tr in ds.trajectories}
    missing = [s for s in scenes if s not in found]
    if missing:
        raise InputError(f"{root}: no windows tables for the scene(s) {missing} (run the workflow first)")
    runs: list[tuple[int, int, list[int]]] = []  # (trajectory, first frame, dataset items)
    prev = None
    for idx, (k, i) in enumerate(ds.items):  # in trajectory, then frame order
        if prev != (k, i - 1):  # a gap in coverage starts a new sequence
            runs.append((k, i, []))
        runs[-1][2].append(idx)
        prev = (k, i)
    out = []
    for n, (k, i0, idxs) in enumerate(runs):
        tr = ds.trajectories[k]
        again = n > 0 and runs[n - 1][0] == k
        inputs, targets = [], []
        for idx in idxs:
            item = ds[idx]
            raw = item["events"]
            H, W = item["rgb"].shape[1:]
            ev = Events(raw["t"].astype(np.int64), raw["x"].astype(np.uint16), raw["y"].astype(np.uint16),
                        raw["p"].astype(np.uint8))
            inputs.append(network_input(ev, (H, W)))
            targets.append(grey(item["rgb"].permute(1, 2, 0).numpy())[..., 0].astype(np.float32))
        out.append(Sequence(f"{tr.scene}/{tr.name}" + (f"@{i0}" if again else ""),
                            np.stack(inputs), np.stack(targets)))
    return out


def recording_sequence(rec) -> Sequence:
    """A :class:`gs2e.events.recordings.Recording` as one sequence: the events
    between consecutive APS frames, scored against the later frame."""
    from gs2e.bench.learned import interval_inputs

    return Sequence(rec.name, np.stack(list(interval_inputs(rec.events, rec.shape, rec.t_us))),
                    rec.frames[1:].astype(np.float32))


def load_network(variant: str):
    """A trainable copy of the shipped network (the cached one stays as shipped)."""
    from gs2e.bench.learned import load

    return copy.deepcopy(load(variant))


def _batch(seqs: list[Sequence], lengths: np.ndarray, s: FinetuneSettings, L: int, crop: int,
           rng: np.random.Generator):
    """(inputs (B, L, 5, c, c), targets (B, L, 1, c, c)) as float32 arrays."""
    eligible = np.nonzero(lengths >= L)[0]
    p = lengths[eligible] / lengths[eligible].sum()  # longer sequences hold more starts
    xs, ys = [], []
    for _ in range(s.batch):
        q = seqs[int(rng.choice(eligible, p=p))]
        t0 = int(rng.integers(0, len(q.inputs) - L + 1))
        H, W = q.targets.shape[1:]
        y0, x0 = int(rng.integers(0, H - crop + 1)), int(rng.integers(0, W - crop + 1))
        x = q.inputs[t0:t0 + L, :, y0:y0 + crop, x0:x0 + crop]
        y = q.targets[t0:t0 + L, None, y0:y0 + crop, x0:x0 + crop]
        if rng.random() < 0.5:  # a mirrored scene is a scene too
            x, y = x[..., ::-1], y[..., ::-1]
        xs.append(x)
        ys.append(y)
    return np.ascontiguousarray(np.stack(xs)), np.ascontiguousarray(np.stack(ys))


def finetune(model, train: list[Sequence], s: FinetuneSettings,
             on_step: Callable[[dict], None] | None = None) -> list[dict]:
    """Fine-tune ``model`` in place on ``train``; returns one row per step
    (``step``, ``loss`` = mean L1, ``cpu_s`` = this process's CPU seconds since
    the start)."""
    import torch

    if not train:
        raise InputError("no training sequences (no covered frame windows in the training scenes)")
    lengths = np.array([len(q.inputs) for q in train])
    L = int(min(s.seq_frames, lengths.max()))
    crop = int(min(s.crop_px, *(min(q.targets.shape[1:]) for q in train)))
    rng = np.random.default_rng(s.seed)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # thread-independent bytes (see the module docstring)
    try:
        torch.manual_seed(s.seed)
        opt = torch.optim.Adam(model.parameters(), lr=s.lr)
        model.train()
        rows, cpu0 = [], time.process_time()
        for step in range(s.steps):
            x, y = _batch(train, lengths, s, L, crop, rng)
            x, y = torch.from_numpy(x), torch.from_numpy(y)
            model.reset_states()
            loss = sum(frame_loss(model(x[:, j])["image"], y[:, j], s.loss) for j in range(L)) / L
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            row = {"step": step + 1, "loss": float(loss.detach()), "cpu_s": time.process_time() - cpu0}
            rows.append(row)
            if on_step is not None:
                on_step(row)
        model.eval()
        model.reset_states()
    finally:
        torch.set_num_threads(threads)
    return rows


def evaluate(model, seqs: list[Sequence], weights: str) -> list[dict]:
    """Per-frame scores of ``model`` on each sequence from a reset state: PSNR,
    SSIM and MSE after EVREAL's robust normalisation (one row per interval)."""
    from gs2e.bench.dataset import score
    from gs2e.bench.learned import robust_normalize, run_network

    rows = []
    for q in seqs:
        for i, out in enumerate(run_network(model, q.inputs)):
            rows.append({"sequence": q.name, "weights": weights, "frame": i + 1,
                         **score(robust_normalize(out)[..., None], q.targets[i][..., None])})
    return rows


def run_finetune_cli(root, train_scenes: list[str], eval_scenes: list[str], real: list[str], out,
                     s: FinetuneSettings) -> None:
    """``gs2e bench-finetune``: read everything first (a bad input fails before
    any training), fine-tune, score shipped and fine-tuned weights, write
    ``out`` (``weights.pt``, ``scores.parquet``, ``history.parquet``,
    ``run.json``) atomically."""
    from pathlib import Path

    import pandas as pd
    import torch

    from gs2e.events.recordings import read_recording
    from gs2e.common.atomic import atomic_dir, check_writable, write_json_atomic
    from gs2e.common.log import get_logger, process_usage
    from gs2e.common.progress import progress

    log = get_logger("gs2e.bench.finetune")
    root = Path(root)
    if not root.is_dir():
        raise InputError(f"{root}: no such results folder")
    if not train_scenes:
        raise ConfigError("--train: name at least one scene")
    both = sorted(set(train_scenes) & set(eval_scenes))
    if both:
        raise ConfigError(f"--eval: {both} also in --train (held-out scenes must differ)")
    check_writable(out)
    t0 = time.perf_counter()
    train = dataset_sequences(root, train_scenes)
    held = dataset_sequences(root, eval_scenes) if eval_scenes else []
    recs = [recording_sequence(read_recording(p)) for p in real]
    log.info("read %d training sequences (%d intervals), %d held-out, %d real in %.1f s",
             len(train), sum(len(q.inputs) for q in train), len(held), len(recs), time.perf_counter() - t0)

    model = load_network(s.variant)
    scored = held + recs
    t1 = time.perf_counter()
    rows = evaluate(model, scored, "shipped")
    eval_s = time.perf_counter() - t1
    bar = progress(None, desc=f"fine-tune {s.variant}", total=s.steps)
    history = finetune(model, train, s, on_step=lambda row: bar.update(1))
    bar.close()
    cpu_train = history[-1]["cpu_s"] if history else 0.0
    log.info("fine-tuned %d steps in %.0f CPU-s", s.steps, cpu_train)
    rows += evaluate(model, scored, "finetuned")
    scores = pd.DataFrame(rows)
    kinds = {q.name: "heldout" for q in held} | {q.name: "real" for q in recs}
    if len(scores):
        scores.insert(0, "data", scores["sequence"].map(kinds))
    cpu_s, peak_mb = process_usage()
    run = {"settings": s.__dict__, "root": str(root), "train": train_scenes, "eval": eval_scenes,
           "real": [str(p) for p in real], "train_sequences": [q.name for q in train],
           "train_intervals": int(sum(len(q.inputs) for q in train)), "train_cpu_s": cpu_train,
           "eval_wall_s_per_weights": eval_s, "process_cpu_s": cpu_s, "peak_rss_mb": peak_mb,
           "torch": torch.__version__}
    with atomic_dir(out) as tmp:
        torch.save(model.state_dict(), tmp / "weights.pt")
        scores.to_parquet(tmp / "scores.parquet", index=False)
        pd.DataFrame(history, columns=["step", "loss", "cpu_s"]).to_parquet(tmp / "history.parquet", index=False)
        write_json_atomic(tmp / "run.json", run)
    for (data, w), g in scores.groupby(["data", "weights"], sort=False) if len(scores) else []:
        log.info("%s, %s weights: PSNR %.2f dB, SSIM %.3f over %d frames", data, w, g["psnr"].mean(),
                 g["ssim"].mean(), len(g))
    log.info("wrote %s in %.0f s (%.0f CPU-s)", out, time.perf_counter() - t0, cpu_s)
