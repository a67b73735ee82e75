"""Tiny user methods for ``gs2e bench --method`` in the tests (see
gs2e.bench.methods for the contract)."""

import numpy as np

CALLS: list = []


def mean_of_neighbours(inp):
    """Deblur: the mean of the blurred frame and its neighbours (a worse
    'method' than doing nothing where the camera moves); video: the keyframe."""
    CALLS.append((inp.task, inp.frame, len(inp.events), inp.t0_us, inp.t1_us))
    if inp.task == "video":
        return inp.keyframe
    frames = [f for f in (inp.blurred_prev, inp.blurred, inp.blurred_next) if f is not None]
    return np.mean(frames, axis=0)


def wrong_shape(inp):
    return np.zeros((3, 3))
