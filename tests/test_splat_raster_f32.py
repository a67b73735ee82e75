"""The float32 forward compositing kernel (16 pixels per vector; renders that
no backward follows: the event stage, the render stage, evaluations) against
a pixel-by-pixel float32 loop of the same rules (same bits: the spans only
pre-filter; both with fused multiply-adds), against the float64 kernel
(rounding only), its exp within 1.1 float32 ulp of the exact exponential,
and the fused multiply-add against exact rationals."""

from __future__ import annotations

import os
import subprocess
import sys
from decimal import Decimal, localcontext

import numpy as np
import pytest
import torch

from gs2e.splat import raster as R
from tests.conftest import REPO
from tests.test_splat_raster_exact import _hard_scene, _pixel_loop_forward

f32 = np.float32


@pytest.mark.parametrize("tile,W,H,C", [(16, 61, 37, 3), (16, 40, 33, 4), (8, 33, 20, 2),
                                        (24, 70, 30, 1)])
def test_forward_f32_same_bits_as_pixel_loop(tile, W, H, C):
    n = W * H // 25
    m2, cn, op, feats, bg, depth = _hard_scene(tile + C, n, W, H, f32)
    feats, bg = np.ascontiguousarray(feats[:, :C]), np.ascontiguousarray(bg[:C])
    offsets, gids = R.bin_gaussians(m2, depth, np.full(n, 40.0), W, H, tile, op)
    out, out_T, nc = R.rasterize_forward(m2, cn, op, feats, bg, W, H, offsets, gids, tile,
                                         compute_dtype=f32)
    ref, ref_T, ref_nc = _pixel_loop_forward(m2, cn, op, feats, bg, W, H, offsets, gids, tile,
                                             ftype=f32, exp_neg=R._exp_neg_f32)
    np.testing.assert_array_equal(out, ref)
    np.testing.assert_array_equal(out_T, ref_T)
    np.testing.assert_array_equal(nc, ref_nc)
    tiles_x = (W + tile - 1) // tile
    ti = (np.arange(H)[:, None] // tile) * tiles_x + np.arange(W)[None, :] // tile
    assert (nc < np.diff(offsets)[ti]).sum() >= 3  # some pixels stopped early
    assert float(out_T.max()) > 0.3  # ... and some stayed open


def test_exp_f32_within_1_1_ulp():
    xs = np.concatenate([-np.linspace(0, 4.5, 20001), -np.arange(289) / 64 - 1 / 128,
                         -np.arange(289) / 64 + 1 / 128, [-4.5, -1e-30, -0.0]]).astype(f32)
    xs = xs[(xs <= 0) & (xs >= -4.5)]
    with localcontext() as ctx:
        ctx.prec = 40
        worst = 0.0
        for x in xs:
            exact = Decimal(float(x)).exp()
            got = R._exp_neg_f32(x)
            assert float(f32(got)) == got  # a float32 value (numba boxes it as a float)
            ulp = np.spacing(f32(float(exact)))
            worst = max(worst, float(abs(Decimal(float(got)) - exact) / Decimal(float(ulp))))
    assert worst <= 1.1, worst
    assert R._exp_neg_f32(f32(0.0)) == 1.0
    assert R._exp_neg_f32(f32(-0.0)) == 1.0


def test_exp_f32_every_float32_of_a_range_and_monotone():
    """Every float32 in [-4.5, -4.4] and [-0.36, -0.34] (the ends of the
    range and of the reduction, where i changes: r at its largest) against
    float64's exp (itself within 0.5 float64 ulp: far below float32's)."""
    from numba import njit

    @njit
    def ev(x, out):
        for k in range(x.shape[0]):
            out[k] = R._exp_neg_f32(x[k])

    worst = 0.0
    for lo, hi in ((-4.50001, -4.4), (-0.36, -0.34), (-3.5, -3.45)):
        bits = np.arange(f32(hi).view(np.int32), f32(lo).view(np.int32) + 1, dtype=np.int64)
        x = bits.astype(np.int32).view(f32)
        got = np.empty_like(x)
        ev(x, got)
        exact = np.exp(x.astype(np.float64))
        worst = max(worst, float((np.abs(got - exact) / np.spacing(exact.astype(f32))).max()))
        assert (np.diff(got) <= 0).all()  # x decreases along the array: so does exp
    assert worst <= 1.1, worst


def test_mul_add_fused_in_float32_plain_in_float64():
    """The compiled multiply-add against the exact rational reference: float32
    triples with cancellation (c ~ -a b, where one rounding and two differ
    most), tiny and huge magnitudes; float64 keeps a * b + c as written."""
    from numba import njit

    @njit
    def ma(a, b, c, out):
        for k in range(a.shape[0]):
            out[k] = R._mul_add(a[k], b[k], c[k])

    rng = np.random.default_rng(3)
    n = 4000
    a = rng.uniform(-2, 2, n).astype(f32)
    b = (rng.uniform(-2, 2, n) * 10.0 ** rng.integers(-6, 6, n)).astype(f32)
    c = rng.uniform(-1, 1, n).astype(f32)
    c[: n // 2] = -(a[: n // 2].astype(np.float64) * b[: n // 2]).astype(f32)  # cancellation
    got = np.empty(n, f32)
    ma(a, b, c, got)
    ref = np.array([R._mul_add(x, y, z) for x, y, z in zip(a, b, c)], dtype=f32)
    np.testing.assert_array_equal(got, ref)
    two_roundings = (a * b + c).astype(f32)  # numpy: product rounded, then the sum
    assert (got != two_roundings).sum() > n // 10  # fused: it differs where rounding did
    a64, b64, c64 = (v.astype(np.float64) for v in (a, b, c))
    got64 = np.empty(n)
    ma(a64, b64, c64, got64)
    np.testing.assert_array_equal(got64, a64 * b64 + c64)


def _big_scene(seed=5, n=3000, W=197, H=131):
    m2, cn, op, feats, bg, depth = _hard_scene(seed, n, W, H, f32)
    feats, bg = np.ascontiguousarray(feats[:, :3]), np.ascontiguousarray(bg[:3])
    offsets, gids = R.bin_gaussians(m2, depth, np.full(n, 40.0), W, H, 16, op)
    return (m2, cn, op, feats, bg, W, H, offsets, gids)


def test_forward_f32_against_float64_rounding_only():
    """Same inputs, float32 against float64 compositing: rounding apart, the
    same image. Where rounding moves a pixel across one of the rules' cuts
    (alpha 1/255 or the 3-sigma rim: that Gaussian weighs ~1/255 there;
    transmittance 1e-4: the stop moves by one Gaussian) a pixel differs by at
    most about one such weight."""
    args = _big_scene()
    o32, T32, nc32 = R.rasterize_forward(*args, compute_dtype=f32)
    o64, T64, nc64 = R.rasterize_forward(*args, compute_dtype=np.float64)
    assert (nc32 == nc64).mean() > 0.999
    d = np.abs(o32.astype(np.float64) - o64)
    assert np.quantile(d, 0.999) < 2e-5, np.quantile(d, 0.999)
    # ... except where a needle's power (det ~1e-9 here: near-singular conic)
    # cancels to within rounding of 0 near its centre, and rounding puts it
    # above 0, the rule that skips the Gaussian (one pixel of 25,807 here)
    far = d.max(axis=2) >= 1.1 / 255 * float(np.abs(args[3]).max())
    assert far.sum() <= 2, far.sum()
    assert np.quantile(np.abs(T32.astype(np.float64) - T64), 0.999) < 2e-5
    assert (o32 != o64).any()  # it did compute in float32


def _at_thread_counts(fn):
    """fn() at 1 thread and at 2 (where numba may use 2), numba's setting restored."""
    import numba

    outs = []
    n0 = numba.get_num_threads()
    try:
        for nt in sorted({1, min(2, numba.config.NUMBA_NUM_THREADS)}):
            numba.set_num_threads(nt)
            outs.append(fn())
    finally:
        numba.set_num_threads(n0)
    return outs


def test_forward_f32_same_bits_whatever_the_thread_count():
    args = _big_scene(seed=9)
    outs = _at_thread_counts(lambda: R.rasterize_forward(*args, compute_dtype=f32))
    for a, b in zip(outs[0], outs[-1]):
        np.testing.assert_array_equal(a, b)


def _grads(args, dt, g_seed=0):
    m2, cn, op, feats, bg, W, H, offsets, gids = args
    f4 = np.ascontiguousarray(np.concatenate([feats, np.ones((len(feats), 1), f32)], axis=1))
    out, out_T, nc = R.rasterize_forward(m2, cn, op, f4, np.zeros(4, f32), W, H, offsets, gids,
                                         compute_dtype=dt)
    rng = np.random.default_rng(g_seed)
    g_out, g_T = rng.standard_normal(out.shape), rng.standard_normal(out_T.shape)
    return R.rasterize_backward(m2, cn, op, f4, W, H, offsets, gids, out_T, nc, g_out, g_T,
                                compute_dtype=dt)


def test_backward_f32_against_float64():
    """The float32 backward (training at splat.compute_dtype float32) follows
    its own forward's stops and recomputes its power, exp and alpha: against
    the float64 backward the gradients differ by rounding (and, where rounding
    moves a pixel across a cut, by that pixel's share), on hard cases."""
    args = _big_scene(seed=7)
    g64, g32 = _grads(args, np.float64), _grads(args, f32)
    assert g32.dtype == np.float64  # pair sums are reduced in float64 either way
    scale = np.abs(g64).max(axis=0)
    d = np.abs(g32 - g64) / scale
    assert (np.quantile(d, 0.99, axis=0) < 1e-5).all(), np.quantile(d, 0.99, axis=0)
    assert (np.median(d, axis=0) < 1e-6).all()
    assert (d.max(axis=0) < 2e-2).all(), d.max(axis=0)
    assert (g32 != g64).any()


def test_backward_f32_same_bits_whatever_the_thread_count():
    args = _big_scene(seed=11)
    outs = _at_thread_counts(lambda: _grads(args, f32))
    np.testing.assert_array_equal(outs[0], outs[-1])


def test_rasterize_grad_dtype_float32():
    """rasterize(..., grad_dtype='float32'): gradients within rounding of the
    float64 ones at torch level; a wrong name is an InputError."""
    from splat_scenes import _loss, _render, look_at_camera, random_scene

    from gs2e.common.errors import InputError
    from gs2e.splat.rasterize import rasterize

    cam = look_at_camera()
    grads = {}
    for gd in ("float64", "float32"):
        q = random_scene(300, seed=4, dtype=torch.float32)
        _loss(_render(rasterize, q, cam, grad_dtype=gd)).backward()
        grads[gd] = {k: v.grad.clone() for k, v in q.items()}
    for k, g64 in grads["float64"].items():
        g32 = grads["float32"][k]
        assert torch.allclose(g32, g64, rtol=1e-3, atol=1e-4 * float(g64.abs().max())), k
        assert not torch.equal(g32, g64) or k == "background", k
    with pytest.raises(InputError, match="grad_dtype"):
        _render(rasterize, q, cam, grad_dtype="float16")


def test_float32_falls_back_to_float64_for_lists_float32_cannot_count():
    small = np.array([0, 5, 9], np.int64)
    huge = np.array([0, 5, 5 + R.F32_MAX_LIST], np.int64)
    assert R.forward_kernel(f32, small) is R.raster_forward_kernel_f32
    assert R.forward_kernel(f32, huge) is R.raster_forward_kernel
    assert R.forward_kernel(np.float64, small) is R.raster_forward_kernel
    assert R.backward_kernel(f32, small) is R.raster_backward_kernel_f32
    assert R.backward_kernel(f32, huge) is R.raster_backward_kernel
    assert R.backward_kernel(np.float64, small) is R.raster_backward_kernel


def test_rasterize_computes_float32_only_where_no_gradient_can_follow(monkeypatch):
    """The backward recomputes the forward in float64, so a render that may be
    differentiated composites in float64; float32 only under no_grad or with
    no input requiring a gradient (float64 inputs: always float64)."""
    from splat_scenes import look_at_camera, random_scene

    from gs2e.splat.rasterize import rasterize

    asked = []
    real = R.forward_kernel
    monkeypatch.setattr(R, "forward_kernel", lambda dt, off, window="cut": asked.append(np.dtype(dt)) or real(dt, off, window))
    cam = look_at_camera()
    p = random_scene(300, seed=5, dtype=torch.float32)
    keys = ("means", "quats", "log_scales", "opacity_logits", "sh")
    img_grad = rasterize(*(p[k] for k in keys), cam)[0]
    assert any(p[k].requires_grad for k in keys) and asked[-1] == np.float64
    img_grad.sum().backward()  # the backward still runs on that forward
    with torch.no_grad():
        img_nograd = rasterize(*(p[k] for k in keys), cam)[0]
    assert asked[-1] == np.float32
    rasterize(*(p[k].detach() for k in keys), cam)
    assert asked[-1] == np.float32
    p64 = random_scene(300, seed=5, dtype=torch.float64)
    with torch.no_grad():
        rasterize(*(p64[k] for k in keys), cam)
    assert asked[-1] == np.float64
    d = (img_grad.detach() - img_nograd).abs()
    assert 0 < float(d.max()) < 1e-4


def test_float32_kernel_same_bits_at_numba_opt_levels():
    """As tests/test_numba_opt.py for the float64 kernels (slow tier there):
    the float32 kernel at LLVM -O1 (the test tier) and -O3 (the pipeline)."""
    script = (
        "import hashlib, numpy as np\n"
        "from tests.test_splat_raster_f32 import _big_scene\n"
        "from gs2e.splat import raster as R\n"
        "h = hashlib.sha256()\n"
        "for a in R.rasterize_forward(*_big_scene(seed=11), compute_dtype=np.float32):\n"
        "    h.update(np.ascontiguousarray(a).tobytes())\n"
        "print('sha256', h.hexdigest())\n")
    digests = set()
    for opt in ("1", "3"):
        env = {**os.environ, "NUMBA_OPT": opt, "NUMBA_CACHE_DIR": os.path.join(
            os.environ.get("TMPDIR", "/tmp"), f"gs2e_numba_f32_O{opt}_{os.getpid()}")}
        p = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True,
                           text=True, timeout=1800)
        assert p.returncode == 0, p.stderr[-3000:]
        digests.add([ln for ln in p.stdout.splitlines() if ln.startswith("sha256")][-1])
    assert len(digests) == 1, digests


def test_forward_kernels_load_from_numba_cache_in_a_new_process(tmp_path):
    """The kernels are closures (one per precision); numba keys a closure's
    cache entry by its captured values, so those must pickle the same in
    every process or each process recompiles (seconds per stage job)."""
    script = (
        "import numpy as np\n"
        "from tests.test_splat_raster_f32 import _big_scene\n"
        "from gs2e.splat import raster as R\n"
        "a = _big_scene(n=50, W=40, H=30)\n"
        "for dt in (np.float32, np.float64):\n"
        "    R.rasterize_forward(*a, compute_dtype=dt)\n"
        "k32, k64 = R.raster_forward_kernel_f32, R.raster_forward_kernel\n"
        "print('stats', sum(k32.stats.cache_hits.values()), sum(k32.stats.cache_misses.values()),\n"
        "      sum(k64.stats.cache_hits.values()), sum(k64.stats.cache_misses.values()))\n")
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache")}
    runs = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", script], cwd=REPO, env=env, capture_output=True,
                           text=True, timeout=1800)
        assert p.returncode == 0, p.stderr[-3000:]
        runs.append([int(x) for x in p.stdout.split("stats")[-1].split()])
    assert runs[0][1] >= 1 and runs[0][3] >= 1  # first process: compiled (and saved)
    assert runs[1] == [1, 0, 1, 0], runs[1]  # second: loaded, nothing compiled
