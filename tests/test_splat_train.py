"""Trainer tests: quality gain, bit-exact resume, density control and optimiser
state, plateau stop, drop-in PLY models, bad input and NaN reporting.

The scenes are tiny demo scenes (12 views at 96x72, ground-truth poses and
surface points from the demo generator, no SfM) so the whole module runs in
well under two minutes on 2 cores.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shutil
from pathlib import Path

import gs2e  # noqa: F401  (first: sets OMP_WAIT_POLICY before torch loads OpenMP)

import numpy as np
import pandas as pd
import pytest
import torch

from gs2e.common.errors import ConfigError, InputError
from gs2e.io.scene import read_scene, write_scene_json
from gs2e.splat.init import init_from_points
from gs2e.splat.ply import read_ply, write_ply
from gs2e.splat.rasterize import NonFiniteError
from gs2e.splat.scene_stats import choose_sh_degree, detail_budget
from gs2e.splat.settings import SplatSettings
from gs2e.splat.strategy import (PARAMS, Adam, DensifyConfig, DensifyStrategy, GradStats,
                                 densify_and_prune, reset_opacity)
from gs2e.splat.model import to_params
from gs2e.splat.evaluate import evaluate, render_views
from gs2e.splat.train import train
from gs2e.splat.views import load_views, split_views

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")

BG = torch.zeros(3)


def cfg(**kw) -> SplatSettings:
    """Validated splat settings for tiny scenes (short schedule)."""
    base = {"max_iterations": 150, "min_iterations": 0, "eval_every": 50, "sh_degree": 0,
            "resolution_schedule": [[0, 2], [50, 1]], "densify_from": 20, "densify_every": 30,
            "densify_until": 120, "opacity_reset_every": 10000, "checkpoint_every": 0,
            "budget": 4000}
    return SplatSettings.defaults(**{**base, **kw})


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory) -> Path:
    from gs2e.demo.io import generate_demo_scene
    from gs2e.demo.settings import DemoSettings

    out = tmp_path_factory.mktemp("splat_train") / "tiny"
    generate_demo_scene(out, DemoSettings.defaults(n_views=12, width=96, height=72, n_points=2000))
    return out


def copy_scene(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def model_digest(out: Path) -> str:
    info = json.loads((out / "model.json").read_text())
    return hashlib.sha256((out / info["ply"]).read_bytes()).hexdigest()


# ----------------------------------------------------------------- training
def test_training_improves_heldout_psnr(tiny_scene, tmp_path):
    c = cfg(max_iterations=200)
    scene = read_scene(tiny_scene)
    views = load_views(tiny_scene, scene, [1])
    _, test_v = split_views(views, c.test_every)
    assert len(test_v) == 2
    g0 = init_from_points(scene.points_xyz, scene.points_rgb, sh_degree=0)
    before = evaluate(to_params(g0), test_v, BG, 0)

    st = train(tiny_scene, tmp_path / "m", c, seed=0, scene_id="tiny")
    assert st["stop_reason"] == "max_iterations" and st["iterations"] == 200
    assert st["test_psnr"] > before["psnr"] + 3.0, (before, st["test_psnr"])
    assert st["test_ssim"] > before["ssim"] + 0.1, (before, st["test_ssim"])
    assert st["n_gaussians"] <= 4000
    out = tmp_path / "m"
    info = json.loads((out / "model.json").read_text())
    assert info["iterations"] == 200 and (out / info["ply"]).exists()
    assert (out / "cameras.json").exists()
    curve = pd.read_parquet(out / "curve.parquet")
    assert list(curve["iteration"]) == [50, 100, 150, 200]
    assert curve["train_time_s"].is_monotonic_increasing and curve["cpu_time_s"].is_monotonic_increasing
    assert list(curve["downscale"]) == [2, 1, 1, 1]  # factor of the step just taken
    m = pd.read_parquet(out / "metrics.parquet")
    assert m.loc[0, "scene_id"] == "tiny" and m.loc[0, "stage"] == "train"
    assert m.loc[0, "test_psnr"] == pytest.approx(st["test_psnr"])
    assert m.loc[0, "test_lpips"] is None or pd.isna(m.loc[0, "test_lpips"])  # recorded as missing

    # the written model renders to the same held-out figures
    rows = render_views(out, tiny_scene, tmp_path / "renders", "test", c.test_every)
    assert len(rows) == 2 and len(list((tmp_path / "renders").glob("*.png"))) == 2
    assert np.mean([r["psnr"] for r in rows]) == pytest.approx(st["test_psnr"], abs=0.05)


def test_float64_and_float32_training_reach_the_same_quality(tiny_scene, tmp_path):
    """splat.compute_dtype: the float32 passes train to the float64 ones'
    held-out quality; the two differ (each computed in its type); ``auto``
    (the default) trains a scene this small in float64, the same bytes."""
    st = {dt: train(tiny_scene, tmp_path / dt, cfg(max_iterations=150, compute_dtype=dt), seed=0,
                    scene_id="tiny") for dt in ("float32", "float64", "auto")}
    assert st["float32"]["compute_dtype"] == "float32"
    assert st["auto"]["compute_dtype"] == "float64"
    assert abs(st["float32"]["test_psnr"] - st["float64"]["test_psnr"]) < 0.3, st
    assert st["float32"]["test_psnr"] != st["float64"]["test_psnr"]
    ply = "point_cloud/iteration_150/point_cloud.ply"
    assert (tmp_path / "auto" / ply).read_bytes() == (tmp_path / "float64" / ply).read_bytes()


def test_auto_compute_dtype_by_training_size():
    from gs2e.splat.optimise import F32_TRAIN_MIN_PIXELS, training_dtype

    assert training_dtype("auto", (1280, 960)) == "float32"  # IMX636's training size
    assert training_dtype("auto", (349, 260)) == "float32"   # DAVIS346's
    assert training_dtype("auto", (640, 480)) == "float32"
    assert training_dtype("auto", (255, 191)) == "float32"   # the demo's
    assert training_dtype("auto", (128, 96)) == "float64"    # below every size measured
    assert training_dtype("auto", (F32_TRAIN_MIN_PIXELS, 1)) == "float32"
    assert training_dtype("auto", (F32_TRAIN_MIN_PIXELS - 1, 1)) == "float64"
    assert training_dtype("float64", (4000, 3000)) == "float64"
    assert training_dtype("float32", (10, 10)) == "float32"


def test_resume_gives_identical_bytes(tiny_scene, tmp_path):
    """Interrupt after 45 steps (mid-epoch, between densifications, with
    densification statistics pending) and resume: same bytes as one run."""
    c = cfg(max_iterations=110, sh_degree=1, sh_increase_every=50, densify_until=100,
            opacity_reset_every=80)  # every stateful feature is active around the interruption
    train(tiny_scene, tmp_path / "a", c, seed=3)
    r = train(tiny_scene, tmp_path / "b", c, seed=3, interrupt_after=45)
    assert r["interrupted"] and r["iteration"] == 45
    assert not (tmp_path / "b").exists() and (tmp_path / "b.ckpt" / "checkpoint.pt").exists()
    st = train(tiny_scene, tmp_path / "b", c, seed=3)
    assert st["iterations"] == 110
    assert model_digest(tmp_path / "a") == model_digest(tmp_path / "b")
    assert not (tmp_path / "b.ckpt").exists()  # removed after success
    ca, cb = (pd.read_parquet(tmp_path / d / "curve.parquet") for d in "ab")
    assert list(ca["psnr"]) == list(cb["psnr"]) and list(ca["n_gaussians"]) == list(cb["n_gaussians"])

    # a checkpoint of another seed (or config) is ignored, not resumed
    train(tiny_scene, tmp_path / "c", c, seed=4, interrupt_after=45)
    for d, seed, other in (("d", 3, c), ("e", 4, c.replace(lr_opacity=0.02)), ("f", 4, c)):
        shutil.copytree(tmp_path / "c.ckpt", tmp_path / f"{d}.ckpt")
        r = train(tiny_scene, tmp_path / d, other, seed=seed, interrupt_after=5)
        assert r["iteration"] == (46 if d == "f" else 5)  # only the matching one resumes


def test_plateau_stop_on_converged_scene(tiny_scene, tmp_path):
    """With (almost) zero learning rates nothing changes: the first evaluation
    sets the best PSNR, the full-resolution ones after it stall and count."""
    tiny = 1e-12
    c = cfg(max_iterations=1000, eval_every=10, plateau_patience=2, resolution_schedule=[[0, 2], [25, 1]],
            densify_until=0, lr_position_init=tiny, lr_position_final=tiny, lr_sh_dc=tiny,
            lr_sh_rest=tiny, lr_opacity=tiny, lr_scaling=tiny, lr_rotation=tiny)
    st = train(tiny_scene, tmp_path / "m", c)
    assert st["stop_reason"] == "plateau"
    # evaluations at 10 (best), 20 (coarse: does not count), 30, 40 (stalled)
    assert st["iterations"] == 40
    # min_iterations holds the stop back
    st = train(tiny_scene, tmp_path / "m2", c.replace(min_iterations=80))
    assert st["stop_reason"] == "plateau" and st["iterations"] == 80
    # an opacity reset at step 30 (after that step's evaluation, which sees the
    # model as trained) drops the PSNR at 40: tracking restarts there instead of
    # counting the dip as stalls (40 sets the new best, 50 and 60 stall)
    st = train(tiny_scene, tmp_path / "m3", c.replace(opacity_reset_every=30, densify_until=100,
                                                       densify_every=1000))
    assert st["stop_reason"] == "plateau" and st["iterations"] == 60
    curve = pd.read_parquet(tmp_path / "m3" / "curve.parquet")
    assert curve["psnr"].iloc[3] < curve["psnr"].iloc[2] - 1.0  # the reset's dip, at 40


def test_ply_import_renders_and_evaluates(tiny_scene, tmp_path):
    scene = read_scene(tiny_scene)
    g = init_from_points(scene.points_xyz, scene.points_rgb, sh_degree=1)
    g["sh"][:, 1:] = np.random.default_rng(0).normal(0, 0.05, g["sh"][:, 1:].shape)
    official = tmp_path / "official"
    write_ply(official / "point_cloud" / "iteration_7000" / "point_cloud.ply", **g)
    write_ply(official / "point_cloud" / "iteration_500" / "point_cloud.ply", **{**g, "means": g["means"] + 1})

    bg = [0.2, 0.5, 0.9]  # the model's background must follow it to render-views
    c = cfg(model_source="ply", ply_path=str(official), background=bg)
    st = train(tiny_scene, tmp_path / "m", c, scene_id="tiny")
    assert st["source"] == "ply" and st["iterations"] == 7000 and st["sh_degree"] == 1
    assert st["ply_path"].endswith("iteration_7000/point_cloud.ply")
    views = load_views(tiny_scene, scene, [1])
    _, test_v = split_views(views, c.test_every)
    # scored and rendered with splat.window (the default, smooth), as every stage renders it
    assert st["window"] == c.window == "smooth"
    ref = evaluate(to_params(g), test_v, torch.tensor(bg), 1, window="smooth")
    assert ref["psnr"] < evaluate(to_params(g), test_v, BG, 1, window="smooth")["psnr"] - 0.5  # bg matters
    assert st["test_psnr"] == pytest.approx(ref["psnr"], abs=1e-4)
    assert st["test_ssim"] == pytest.approx(ref["ssim"], abs=1e-5)
    back = read_ply(tmp_path / "m" / "point_cloud" / "iteration_7000" / "point_cloud.ply")
    for k in g:
        np.testing.assert_array_equal(back[k], np.asarray(g[k], np.float32))
    rows = render_views(tmp_path / "m", tiny_scene, tmp_path / "r", "test")
    assert np.mean([r["psnr"] for r in rows]) == pytest.approx(ref["psnr"], abs=1e-3)

    # a single file works too
    c = cfg(model_source="ply", background=bg,
            ply_path=str(official / "point_cloud" / "iteration_7000" / "point_cloud.ply"))
    assert train(tiny_scene, tmp_path / "m3", c)["test_psnr"] == pytest.approx(ref["psnr"], abs=1e-4)
    # as the official code trained it: the cut window
    st = train(tiny_scene, tmp_path / "m4", c.replace(window="cut"))
    assert st["window"] == "cut"
    assert st["test_psnr"] == pytest.approx(evaluate(to_params(g), test_v, torch.tensor(bg), 1, window="cut")["psnr"],
                                            abs=1e-4)


# ----------------------------------------------------------------- bad input
def test_too_few_points(tiny_scene, tmp_path):
    scene_dir = copy_scene(tiny_scene, tmp_path / "s")
    scene = read_scene(scene_dir)
    scene.points_xyz, scene.points_rgb = scene.points_xyz[:5], scene.points_rgb[:5]
    write_scene_json(scene, scene_dir)
    with pytest.raises(InputError, match=r"points3d\.npz.*too few points.*min_points"):
        train(scene_dir, tmp_path / "m", cfg())
    assert not (tmp_path / "m").exists()


def test_missing_pose(tiny_scene, tmp_path):
    scene_dir = copy_scene(tiny_scene, tmp_path / "s")
    scene = read_scene(scene_dir)
    scene.frames[3].c2w = None
    write_scene_json(scene, scene_dir)
    with pytest.raises(InputError, match=r"003\.png has no pose"):
        train(scene_dir, tmp_path / "m", cfg())
    assert not (tmp_path / "m").exists()


@pytest.mark.parametrize("damage", ["truncated", "nan", "missing_attr", "no_path"])
def test_bad_ply_model(tiny_scene, tmp_path, damage):
    scene = read_scene(tiny_scene)
    g = init_from_points(scene.points_xyz, scene.points_rgb, sh_degree=0)
    path = tmp_path / "point_cloud.ply"
    write_ply(path, **g)
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[:-1000])
        pattern = "cannot read Gaussian model"
    elif damage == "nan":
        data = bytearray(path.read_bytes())
        head = data.index(b"end_header\n") + len(b"end_header\n")
        data[head:head + 4] = np.float32(np.nan).tobytes()  # x of the first Gaussian
        path.write_bytes(bytes(data))
        pattern = "NaN/inf in means"
    elif damage == "missing_attr":
        from plyfile import PlyData, PlyElement

        from numpy.lib.recfunctions import repack_fields

        v = PlyData.read(str(path))["vertex"].data
        names = [n for n in v.dtype.names if n != "opacity"]
        PlyData([PlyElement.describe(repack_fields(v[names]), "vertex")]).write(str(path))
        pattern = "missing vertex attributes opacity"
    else:
        pattern = "ply_path is not set"
        # The config check catches it before any job; train still refuses
        # settings built past that check.
        with pytest.raises(ConfigError, match="splat.ply_path: must be set"):
            cfg(model_source="ply", ply_path=None)
    c = cfg(model_source="ply", ply_path=str(path))
    if damage == "no_path":
        c = dataclasses.replace(c, ply_path=None)
    with pytest.raises(InputError, match=pattern):
        train(tiny_scene, tmp_path / "m", c)
    assert not (tmp_path / "m").exists()


def test_nan_parameters_are_reported_not_propagated(tiny_scene, tmp_path):
    """A NaN in the parameters (here: injected into a checkpoint) stops
    training with a NonFiniteError naming the step; nothing is written."""
    c = cfg(max_iterations=60)
    train(tiny_scene, tmp_path / "m", c, interrupt_after=20)
    ckpt = tmp_path / "m.ckpt" / "checkpoint.pt"
    st = torch.load(ckpt, weights_only=False)
    st["params"]["means"][7, 1] = float("nan")
    torch.save(st, ckpt)
    with pytest.raises(NonFiniteError, match=r"training step 21 .*means holds 1 non-finite value.*rows \[7\]"):
        train(tiny_scene, tmp_path / "m", c)
    assert not (tmp_path / "m").exists()


# ----------------------------------------------------------------- density control
def _toy(n=6, seed=0):
    """Gaussians 0,1 small (clone), 2,3 large (split), 4 low gradient, 5 transparent."""
    rng = np.random.default_rng(seed)
    p = {"means": torch.tensor(rng.normal(size=(n, 3)), dtype=torch.float32),
         "quats": torch.tensor(rng.normal(size=(n, 4)), dtype=torch.float32),
         "log_scales": torch.full((n, 3), math.log(0.005)),
         "opacity_logits": torch.zeros(n),
         "sh_dc": torch.arange(n, dtype=torch.float32).view(n, 1, 1).repeat(1, 1, 3),
         "sh_rest": torch.zeros(n, 3, 3)}
    p["log_scales"][2:4] = math.log(0.1)
    p["opacity_logits"][5] = -8.0  # opacity 3e-4
    stats = GradStats.zeros(n)
    stats.grad_accum[:] = torch.tensor([5e-4, 6e-4, 7e-4, 8e-4, 1e-5, 1e-5], dtype=torch.float64)
    stats.count[:] = 1
    return p, stats


def _adam_with_marked_rows(p):
    opt = Adam({k: 1e-3 for k in PARAMS})
    opt.step(p, {k: torch.ones_like(v) for k, v in p.items()})  # creates the moments
    for k in PARAMS:  # moment row i = i + 1, to follow rows through densification
        shape = (-1,) + (1,) * (p[k].dim() - 1)
        opt.m[k] = (torch.arange(p[k].shape[0], dtype=torch.float32).view(shape) + 1).expand_as(p[k]).clone()
        opt.v[k] = opt.m[k].clone() * 10
    return opt


def test_clone_split_prune_counts_and_adam_rows():
    p, stats = _toy()
    opt = _adam_with_marked_rows(p)
    s0 = p["log_scales"].exp()
    res = densify_and_prune(p, opt, stats, DensifyConfig(budget=100), extent=1.0,
                            gen=torch.Generator().manual_seed(0))
    assert res == {"cloned": 2, "split": 2, "pruned": 1, "pruned_big": 0, "n": 6 + 2 + 4 - 2 - 1}
    ids = p["sh_dc"][:, 0, 0].round().long().tolist()
    # survivors in order: originals 0, 1, 4; clones of 0, 1; two children each of 2, 3
    assert ids == [0, 1, 4, 0, 1, 2, 3, 2, 3]
    for k in PARAMS:
        assert p[k].shape[0] == 9 and opt.m[k].shape == p[k].shape and opt.v[k].shape == p[k].shape
        m = opt.m[k].reshape(9, -1)[:, 0]
        np.testing.assert_array_equal(m[:3].numpy(), [1, 2, 5])  # originals keep their moments
        assert torch.all(m[3:] == 0) and torch.all(opt.v[k].reshape(9, -1)[3:] == 0)
    # clones keep the scale, split children get scale / (0.8 * 2)
    s = p["log_scales"].exp()
    torch.testing.assert_close(s[3:5], s0[[0, 1]])
    torch.testing.assert_close(s[5:], s0[[2, 3, 2, 3]] / 1.6)
    # the next Adam step moves every row (no stale or missing state)
    before = {k: v.clone() for k, v in p.items()}
    opt.step(p, {k: torch.ones_like(v) for k, v in p.items()})
    assert all(torch.all(p[k] != before[k]) for k in PARAMS)


def test_budget_keeps_largest_gradients():
    p, stats = _toy()
    opt = _adam_with_marked_rows(p)
    # room for 3 more: Gaussian 3 (largest gradient, split: +1), 2 (split: +1), 1 (clone: +1)
    res = densify_and_prune(p, opt, stats, DensifyConfig(budget=9), extent=1.0,
                            gen=torch.Generator().manual_seed(0))
    assert (res["cloned"], res["split"]) == (1, 2)
    ids = sorted(p["sh_dc"][:, 0, 0].round().long().tolist())
    assert ids == [0, 1, 1, 2, 2, 3, 3, 4]
    assert res["n"] == 8 <= 9
    # a full budget densifies nothing but still prunes
    p, stats = _toy()
    opt = _adam_with_marked_rows(p)
    res = densify_and_prune(p, opt, stats, DensifyConfig(budget=6), extent=1.0,
                            gen=torch.Generator().manual_seed(0))
    assert (res["cloned"], res["split"], res["pruned"], res["n"]) == (0, 0, 1, 5)
    np.testing.assert_array_equal(opt.m["means"][:, 0].numpy(), [1, 2, 3, 4, 5])


def test_prune_big_and_opacity_reset():
    p, stats = _toy()
    opt = _adam_with_marked_rows(p)
    stats.grad_accum.zero_()
    stats.max_radius_px[0] = 50.0  # too large on screen
    res = densify_and_prune(p, opt, stats, DensifyConfig(budget=100, prune_big=True, max_world_frac=0.05),
                            extent=1.0, gen=torch.Generator().manual_seed(0))
    # 0 (screen), 2 and 3 (world: 0.1 > 0.05), 5 (opacity)
    assert res["pruned_big"] == 3 and res["n"] == 2
    np.testing.assert_array_equal(p["sh_dc"][:, 0, 0].round().numpy(), [1, 4])
    np.testing.assert_array_equal(opt.m["quats"][:, 0].numpy(), [2, 5])
    reset_opacity(p, opt)
    assert torch.all(torch.sigmoid(p["opacity_logits"]) <= 0.01 + 1e-7)
    assert torch.all(opt.m["opacity_logits"] == 0) and torch.all(opt.m["means"] != 0)


def test_strategy_owns_the_schedule():
    """Densify every 2 steps from 2 until 7, reset opacities every 4; oversized
    Gaussians are pruned only after the first reset."""
    p, _ = _toy()
    opt = _adam_with_marked_rows(p)
    c = cfg(densify_from=2, densify_every=2, densify_until=7, opacity_reset_every=4)
    strategy = DensifyStrategy.from_config(c, budget=1000, extent=1.0)
    assert (strategy.ops.grad_threshold, strategy.ops.budget) == (c.densify_grad_threshold, 1000)
    gen = torch.Generator().manual_seed(0)
    sizes, resets = [], []
    for step in range(1, 10):
        n = p["means"].shape[0]
        # every Gaussian seen with a large gradient, 30 px wide (> max_screen_px)
        meta = {"grad2d": torch.full((n, 2), 1e-2), "radii": torch.full((n,), 30, dtype=torch.int32)}
        resets.append(strategy.step_post_update(p, opt, step, meta, 96, 72, 1, gen))
        sizes.append(p["means"].shape[0])
        assert strategy.stats.grad_accum.shape[0] == p["means"].shape[0]
    assert resets == [False, False, False, True, False, False, False, False, False]
    # every Gaussian has a large gradient here. Step 2: 4 clones (0, 1, 4 and the
    # transparent 5) + 2 x 2 split children - 2 originals - 5 and its clone = 10;
    # step 4: 6 clones + 4 x 2 children - 4 originals = 20; step 6 (after the
    # reset) prunes all 20, seen 30 px wide, and keeps its 12 clones and 8 x 2
    # children; nothing after densify_until
    assert sizes == [6, 10, 10, 20, 20, 28, 28, 28, 28]
    assert torch.all(torch.sigmoid(p["opacity_logits"]) <= 0.01 + 1e-7)  # reset at step 4
    assert strategy.stats.count.sum() == 0  # no statistics after densify_until


def test_grad_stats_resolution_independent():
    """The NDC gradient of the same motion is the same at every downscale."""
    n = 3
    radii = torch.tensor([4, 0, 2], dtype=torch.int32)
    a, b = GradStats.zeros(n), GradStats.zeros(n)
    g_full = torch.tensor([[1e-3, 2e-3], [5.0, 5.0], [0.0, 1e-3]], dtype=torch.float64)
    a.update(g_full, radii, 96, 72, 1)
    b.update(g_full * 4, radii, 24, 18, 4)  # d/dpx grows with the downscale factor
    torch.testing.assert_close(a.mean_grad(), b.mean_grad())
    assert a.count.tolist() == [1, 0, 1] and a.mean_grad()[1] == 0  # invisible: not counted
    assert b.max_radius_px.tolist() == [16, 0, 8]


# ----------------------------------------------------------------- scene analysis
def test_scene_analysis_rules():
    assert choose_sh_degree(None, [0.03, 0.06, 0.1]) == 3  # nothing measured: keep all
    assert [choose_sh_degree(s, [0.03, 0.06, 0.1]) for s in (0.0, 0.04, 0.07, 0.5)] == [0, 1, 2, 3]
    flat = np.full((40, 50, 3), 0.5, np.float32)
    checker = ((np.indices((40, 50)).sum(0) // 5) % 2).astype(np.float32)[..., None].repeat(3, 2)
    assert detail_budget([flat, flat], 2.0, 100, 10**6) == (100, 0.0)  # clipped to the minimum
    budget, edges = detail_budget([checker, checker, flat], 2.0, 100, 10**6)
    assert edges > 300 and budget == int(2 * edges)
    assert detail_budget([checker], 2.0, 100, 500)[0] == 500


def test_cli_train_and_render_views(tiny_scene, tmp_path):
    from conftest import run_cli

    c = {"max_iterations": 30, "min_iterations": 0, "eval_every": 15, "sh_degree": 0,
         "densify_from": 10, "densify_every": 10, "densify_until": 25, "budget": 3000,
         "resolution_schedule": [[0, 1]], "checkpoint_every": 0}
    run_cli("train", "--scene", str(tiny_scene), "--out", str(tmp_path / "m"), "--seed", "1",
            "--scene-id", "tiny", "--config-json", json.dumps(c), check=True)
    stats = json.loads((tmp_path / "m" / "train_stats.json").read_text())
    assert stats["iterations"] == 30 and stats["n_gaussians"] <= 3000
    run_cli("render-views", "--model", str(tmp_path / "m"), "--scene", str(tiny_scene),
            "--out", str(tmp_path / "r"), "--views", "all", check=True)
    assert len(list((tmp_path / "r").glob("*.png"))) == 12
    m = pd.read_parquet(tmp_path / "r" / "metrics.parquet")
    held = m[m["view"].isin(["000.png", "008.png"])]
    assert held["psnr"].mean() == pytest.approx(stats["test_psnr"], abs=0.05)
    # bad input through the CLI: a clear message and a non-zero exit, no output
    p = run_cli("train", "--scene", str(tmp_path / "nope"), "--out", str(tmp_path / "x"))
    assert p.returncode != 0 and "scene.json" in p.stderr and not (tmp_path / "x").exists()


def test_growing_budget_rules():
    """Grows when the count reaches it; judges a growth once the count has
    filled the new room and one more evaluation has passed, on the better of
    the two (a densification dip does not end growth); keeps growing while
    each growth pays min_gain_db, then freezes at the count (never below the
    floor); a resolution change restarts the test."""
    from gs2e.splat.strategy import GrowingBudget

    b = GrowingBudget(1000, budget_max=5000, growth=1.5, min_gain_db=0.1, floor=800)
    assert b.update(100, 20.0, 2, 500) == 1000          # below the budget: nothing to decide
    assert b.update(200, 20.5, 2, 990) == 1500          # reached it: grows
    assert b.update(300, 20.3, 2, 1200) == 1500         # room still filling: no verdict
    assert b.update(400, 19.0, 2, 1450) == 1500         # filled, in a dip: wait one more
    assert b.update(500, 21.5, 1, 1480) == 1500         # resolution changed: restart from here
    assert b.update(600, 21.6, 1, 1490) == 1500         # filled at this resolution
    assert b.update(700, 21.7, 1, 1495) == 2250         # best +0.2 dB: pays, grows at once
    assert b.update(800, 21.75, 1, 2200) == 2250        # filled
    assert b.update(900, 21.78, 1, 2240) == 2240        # best +0.08 dB over 21.7: frozen at the count
    assert b.frozen and b.update(1000, 30.0, 1, 2240) == 2240
    assert [h[3] for h in b.history] == ["grown", "grown", "frozen"]
    dip = GrowingBudget(1000, budget_max=5000, growth=1.5, min_gain_db=0.1, floor=10)
    assert dip.update(1, 30.0, 1, 1000) == 1500
    assert dip.update(2, 28.0, 1, 1450) == 1500         # a densification dip right after filling
    assert dip.update(3, 30.3, 1, 1460) == 2250 and not dip.frozen  # recovered: +0.3 dB
    c = GrowingBudget(4000, budget_max=5000, growth=2.0, min_gain_db=0.1, floor=800)
    assert c.update(100, 20.0, 1, 3990) == 5000         # capped at budget_max
    assert c.update(200, 20.0, 1, 4900) == 5000
    assert c.update(300, 20.05, 1, 700) == 800          # no gain: frozen, but not below the floor
    d = GrowingBudget(5000, budget_max=5000)
    assert d.update(100, 20.0, 1, 5000) == 5000 and not d.history  # at the maximum: stays


def test_adaptive_budget_grows_past_a_small_start_and_resumes_exactly(tiny_scene, tmp_path):
    """budget=adaptive from a start below what the scene uses: the count
    passes the start, the curve records the budget, and an interrupted run
    resumes to the same bytes (the budget's state is in the checkpoint)."""
    c = cfg(max_iterations=150, budget="adaptive", budget_min=10, budget_max=20000,
            budget_per_edge_pixel=1e-6, budget_growth=1.3, budget_min_gain_db=0.0,
            eval_every=25, densify_every=10)
    st = train(tiny_scene, tmp_path / "a", c, seed=2)
    n0 = len(np.load(tiny_scene / "points3d.npz")["xyz"])
    assert st["budget_growths"] >= 1 and st["budget"] > n0 and st["n_gaussians"] > n0
    curve = pd.read_parquet(tmp_path / "a" / "curve.parquet")
    assert curve["budget"].iloc[0] >= n0 and curve["budget"].is_monotonic_increasing
    train(tiny_scene, tmp_path / "b", c, seed=2, interrupt_after=60)
    st_b = train(tiny_scene, tmp_path / "b", c, seed=2)
    assert model_digest(tmp_path / "a") == model_digest(tmp_path / "b")
    assert st_b["budget"] == st["budget"]


def test_evaluation_sees_the_model_before_that_steps_densification(tiny_scene, tmp_path):
    """An evaluation on a densification step scores the model as trained, not
    with the Gaussians that step has just split or cloned (they cost 1.5-2 dB
    for one evaluation on temple_ring), and the last step does not densify."""
    c = cfg(max_iterations=30, eval_every=10, densify_every=10, densify_from=10, densify_until=30,
            densify_grad_threshold=1e-12)
    st = train(tiny_scene, tmp_path / "m", c, seed=1)
    curve = pd.read_parquet(tmp_path / "m" / "curve.parquet")
    n0 = len(np.load(tiny_scene / "points3d.npz")["xyz"])
    assert list(curve["iteration"]) == [10, 20, 30]
    assert curve["n_gaussians"].iloc[0] == n0  # step 10's densification comes after its evaluation
    assert curve["n_gaussians"].iloc[1] > n0 and st["n_gaussians"] == curve["n_gaussians"].iloc[-1]


def test_smooth_window_trains_records_itself_and_renders_as_trained(tiny_scene, tmp_path):
    """splat.window smooth (issue 67): the model reaches the cut window's
    held-out quality on a tiny scene, model.json records the window, and
    render-views scores it with that window (the same figures)."""
    st = {w: train(tiny_scene, tmp_path / w, cfg(window=w), seed=0, scene_id="tiny")
          for w in ("cut", "smooth")}
    assert st["smooth"]["window"] == "smooth"
    assert json.loads((tmp_path / "smooth" / "model.json").read_text())["window"] == "smooth"
    assert json.loads((tmp_path / "cut" / "model.json").read_text())["window"] == "cut"
    assert abs(st["smooth"]["test_psnr"] - st["cut"]["test_psnr"]) < 0.5, st
    rows = render_views(tmp_path / "smooth", tiny_scene, tmp_path / "renders", "test")
    assert np.mean([r["psnr"] for r in rows]) == pytest.approx(st["smooth"]["test_psnr"], abs=0.05)
