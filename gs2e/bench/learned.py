"""Learned video reconstruction: PIE-Net and PIE-Net-Lite.

PIE-Net (Qu et al., the ``event-pienet`` package, MIT license, weights in the
wheel) is an E2VID-family recurrent network: per frame interval it takes a
5-bin voxel grid of the interval's events (:func:`gs2e.events.represent.voxel_grid`,
polarity +1 / -1 spread bilinearly over the bins, time from the interval's
first to its last event, no normalisation: the package's own demo) and returns
an intensity image in [0, 1] together with its own previous output and
recurrent state. gs2e runs it from a reset state at the video task's keyframe,
one step per rendered frame, on the CPU (one thread: torch's convolutions sum in
a thread-dependent order), and scores its output as EVREAL (Ercan et al., CVPRW
2023) scores E2VID-family methods: after its "robust" post-processing
(:func:`robust_normalize`, the 1st and 99th percentiles to 0 and 1), because
events alone fix intensity only up to an unknown offset and scale; the model-free
methods start from the keyframe and are scored as they are.

The package declares ``opencv-python`` and ``torchvision``, neither of which the
model needs; ``make setup`` installs it (``event-pienet==1.1.3``, the version gs2e is tested with)
with ``pip install --no-deps`` so that ``cv2`` stays
``opencv-contrib-python-headless``; ``gs2e config --validate`` says so when it is
missing and ``bench.video_learned`` is not empty.
"""

from __future__ import annotations

import functools
from typing import Iterable, Iterator, Sequence

import numpy as np

from gs2e.common.errors import ConfigError
from gs2e.events.models import Events
from gs2e.events.represent import voxel_grid

# bench.video_learned name -> the package's variant name
VARIANTS = {"pienet": "pie-net", "pienet_lite": "pie-net-lite"}
N_BINS = 5  # the shipped weights' input channels


@functools.lru_cache(maxsize=None)
def load(name: str):
    """The network of ``name`` (a key of :data:`VARIANTS`) with its shipped
    weights, on the CPU, in eval mode (loaded once per process)."""
    import torch

    try:
        from pie_net import load_model
    except ImportError:  # a job environment without it (e.g. snakemake --sdm conda)
        raise ConfigError(f"bench.video_learned: {name} needs the PIE-Net package, not installed "
                          "in this environment (pip install --no-deps event-pienet==1.1.3; or "
                          "set bench.video_learned=[])") from None
    with torch.no_grad():
        return load_model(pretrained=True, device="cpu", variant=VARIANTS[name]).eval()


def network_input(ev: Events, shape: tuple[int, int]) -> np.ndarray:
    """The network's input for one interval's events: a (N_BINS, H, W) float32
    voxel grid, time from the interval's first to its last event (the
    package's own demo)."""
    return voxel_grid(ev, shape, N_BINS)


def interval_inputs(ev: Events, shape: tuple[int, int], t_us: Sequence[int]) -> Iterator[np.ndarray]:
    """:func:`network_input` per interval (t_us[i - 1], t_us[i]] of the
    time-sorted events ``ev``."""
    edges = np.searchsorted(ev.t, np.asarray(t_us, np.int64), side="right")
    for a, b in zip(edges[:-1], edges[1:]):
        yield network_input(Events(ev.t[a:b], ev.x[a:b], ev.y[a:b], ev.p[a:b]), shape)


def reconstruct_learned(name, ev: Events, shape: tuple[int, int],
                        t_us: Sequence[int]) -> Iterator[np.ndarray]:
    """Run network ``name`` (a key of :data:`VARIANTS`, or a loaded network,
    e.g. a fine-tuned one) over the intervals (t_us[i - 1], t_us[i]] of the
    time-sorted events ``ev``, from a reset state at ``t_us[0]``.

    Yields, per interval, the (H, W) float32 output in [0, 1] at its end (an
    interval without events still advances the recurrence, on a zero grid).
    The network (and its recurrent state) is shared per process: run one
    sequence per network at a time, not two generators of one name interleaved.
    """
    model = load(name) if isinstance(name, str) else name
    return run_network(model, interval_inputs(ev, shape, t_us))


def run_network(model, inputs: Iterable[np.ndarray]) -> Iterator[np.ndarray]:
    """``model`` from a reset state over the (N_BINS, H, W) ``inputs``, one per
    interval: per interval, the (H, W) float32 output in [0, 1]."""
    import torch

    model.reset_states()
    for grid in inputs:
        vox = torch.from_numpy(grid)[None]
        threads = torch.get_num_threads()
        # one thread: torch's CPU convolutions sum in an order that depends on
        # the thread count, and the same config must give the same bytes
        torch.set_num_threads(1)
        try:
            with torch.no_grad():
                out = model(vox)["image"][0, 0].numpy()
        finally:
            torch.set_num_threads(threads)
        yield np.clip(out, 0.0, 1.0).astype(np.float32)


def robust_normalize(img: np.ndarray, q_lo: float = 1.0, q_hi: float = 99.0) -> np.ndarray:
    """EVREAL's "robust" post-processing: the ``q_lo`` / ``q_hi`` percentiles of
    ``img`` mapped to 0 / 1, clipped to [0, 1] (a flat image stays as it is)."""
    lo, hi = np.percentile(img, [q_lo, q_hi])
    if not hi > lo:
        return np.clip(img, 0.0, 1.0).astype(np.float32)
    return np.clip((img - lo) / (hi - lo), 0.0, 1.0).astype(np.float32)
