"""The default test tier compiles numba kernels at LLVM -O1 (tests/conftest.py)
while the pipeline runs them at numba's default -O3. With fastmath off and no
SVML, the optimisation level must not change a single bit: this compiles the
compositing kernels (forward and backward, float64 and float32) and both event
models cold at each level, in separate processes with separate caches, and
compares the bytes; likewise for code generated for other instruction sets."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.conftest import REPO

pytestmark = pytest.mark.slow  # two cold compiles of the kernels below

SCRIPT = r"""
import hashlib
import numpy as np
from gs2e.splat import raster as R
from gs2e.events.models import IdealModel, VoltmeterModel
from gs2e.events.synthetic import standard_sequence

h = hashlib.sha256()
rng = np.random.default_rng(0)
n, W, H = 400, 64, 48
f32 = np.float32
means2d = (rng.random((n, 2)) * [W, H]).astype(f32)
a = rng.uniform(0.02, 0.5, n); c = rng.uniform(0.02, 0.5, n); b = rng.uniform(-0.5, 0.5, n) * np.sqrt(a * c)
conics = np.stack([a, b, c], 1).astype(f32)
opac = rng.uniform(0.05, 0.99, n).astype(f32)
feats = rng.random((n, 3)).astype(f32)
offsets, gids = R.bin_gaussians(means2d, rng.random(n), np.full(n, 12.0), W, H, 16)
out, T, nc = R.rasterize_forward(means2d, conics, opac, feats, np.zeros(3, f32), W, H, offsets, gids)
g = R.rasterize_backward(means2d, conics, opac, feats, W, H, offsets, gids, T, nc,
                         rng.standard_normal(out.shape), rng.standard_normal(T.shape))
for arr in (out, T, nc, *(g if isinstance(g, tuple) else (g,))):
    h.update(np.ascontiguousarray(arr).tobytes())
# the float32 kernels (16 lanes, fused multiply-adds) too
out, T, nc = R.rasterize_forward(means2d, conics, opac, feats, np.zeros(3, f32), W, H, offsets, gids,
                                 compute_dtype=f32)
g = R.rasterize_backward(means2d, conics, opac, feats, W, H, offsets, gids, T, nc,
                         rng.standard_normal(out.shape), rng.standard_normal(T.shape), compute_dtype=f32)
for arr in (out, T, nc, g):
    h.update(np.ascontiguousarray(arr).tobytes())
fr = list(standard_sequence(n_frames=40, width=80, height=60))
ts = np.array([t for t, _ in fr]); seq = np.stack([f for _, f in fr])
for model in (IdealModel(seq.shape[1:], seed=3), VoltmeterModel(seq.shape[1:], seed=3)):
    ev = [model.process_batch(ts[i:i + 16], seq[i:i + 16]) for i in range(0, len(ts), 16)]
    ev.append(model.flush())
    for e in ev:
        h.update(e.t.tobytes() + e.x.tobytes() + e.y.tobytes() + e.p.tobytes())
print("sha256", sum(len(e) for e in ev), h.hexdigest())
"""


def _digest(opt: str, cache: str, **env_extra) -> str:
    env = {**os.environ, "NUMBA_OPT": opt, "NUMBA_CACHE_DIR": cache, **env_extra}
    p = subprocess.run([sys.executable, "-c", SCRIPT], cwd=REPO, env=env, capture_output=True,
                       text=True, timeout=3600)
    assert p.returncode == 0, p.stderr[-3000:]
    line = [ln for ln in p.stdout.splitlines() if ln.startswith("sha256")][-1]
    assert int(line.split()[1]) > 0  # the voltmeter produced events
    return line


def test_optimisation_level_does_not_change_results(tmp_path):
    assert _digest("3", str(tmp_path / "o3")) == _digest("1", str(tmp_path / "o1"))


def test_instruction_set_does_not_change_results(tmp_path):
    """The same bits from code generated for this CPU, for AVX2 + FMA
    (Haswell: what most users' machines run) and for plain x86-64 (SSE2, no
    FMA: llvm.fma becomes a correctly rounded library call): the kernels'
    lane counts are fixed, every lane computes what a pixel loop computes,
    and float32 multiply-adds are fused with one rounding on every target."""
    host = _digest("3", str(tmp_path / "host"))
    assert _digest("3", str(tmp_path / "haswell"), NUMBA_CPU_NAME="haswell") == host
    assert _digest("1", str(tmp_path / "generic"), NUMBA_CPU_NAME="x86-64") == host
