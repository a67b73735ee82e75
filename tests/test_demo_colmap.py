"""COLMAP (pycolmap SIFT + exhaustive matching + incremental mapping) registers
every view of the default demo scene, and the recovered cameras match the
ground truth after a similarity alignment. About 25 s on 2 cores."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gs2e.common.so3 import geodesic_angle, umeyama
from gs2e.config import load_section
from gs2e.demo.io import generate_demo_scene
from gs2e.io.scene import read_scene

pycolmap = pytest.importorskip("pycolmap")


def test_colmap_registers_every_view_of_the_default_demo(tmp_path):
    cfg = load_section("demo")  # the defaults: 36 views at 320x240
    out = tmp_path / "scene"
    generate_demo_scene(out, cfg)
    scene = read_scene(out)
    db = tmp_path / "database.db"
    images = out / "images"

    t0 = time.perf_counter()
    ext = pycolmap.FeatureExtractionOptions()
    ext.num_threads = 2
    pycolmap.extract_features(db, images, camera_mode=pycolmap.CameraMode.SINGLE,
                              extraction_options=ext, device=pycolmap.Device.cpu)
    match = pycolmap.FeatureMatchingOptions()
    match.num_threads = 2
    pycolmap.match_exhaustive(db, matching_options=match, device=pycolmap.Device.cpu)
    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = 2
    opts.random_seed = 0
    recs = pycolmap.incremental_mapping(db, images, tmp_path / "sparse", options=opts)
    seconds = time.perf_counter() - t0

    assert len(recs) >= 1
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    n_reg = rec.num_reg_images()
    err = rec.compute_mean_reprojection_error()
    print(f"\nCOLMAP on the demo scene: {n_reg}/{len(scene.frames)} views registered, "
          f"{rec.num_points3D()} points, mean reprojection error {err:.3f} px, {seconds:.1f} s")
    assert n_reg == cfg["n_views"] == len(scene.frames)
    assert err < 1.0
    assert rec.num_points3D() > 1500

    # recovered intrinsics and poses agree with the ground truth (up to similarity)
    cam = next(iter(rec.cameras.values()))
    assert cam.focal_length == pytest.approx(scene.frames[0].camera.fx, rel=0.02)
    by_name = {im.name: im for im in rec.images.values()}
    gt = scene.c2w_array()
    est_c = np.array([by_name[f.name].projection_center() for f in scene.frames])
    s, R, t = umeyama(est_c, gt[:, :3, 3])
    aligned = s * est_c @ R.T + t
    centre_err = np.linalg.norm(aligned - gt[:, :3, 3], axis=1)
    assert centre_err.max() < 0.02 * cfg["orbit_radius"], centre_err.max()
    est_R_c2w = np.array([R @ by_name[f.name].cam_from_world().rotation.matrix().T
                          for f in scene.frames])
    rot_err_deg = np.degrees(geodesic_angle(est_R_c2w, gt[:, :3, :3]))
    print(f"camera centres vs ground truth after similarity: max {centre_err.max():.4f} units "
          f"(orbit radius {cfg['orbit_radius']}), rotations max {rot_err_deg.max():.3f} deg, "
          f"focal {cam.focal_length:.2f} px vs {scene.frames[0].camera.fx:.2f} px")
    assert rot_err_deg.max() < 1.0, rot_err_deg.max()
