"""Rendering along trajectories: motion blur, records."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from gs2e.common.color import linear_to_srgb, srgb_to_linear
from gs2e.common.errors import ConfigError, InputError
from gs2e.config import load_config
from gs2e.io.scene import Camera, Frame, Scene
from gs2e.render.blur import average_srgb, subframe_times_us, subframes_needed
from gs2e.render.settings import RenderSettings

from gs2e.testing import PLANE_DEPTH as DEPTH, PLANE_F as F, PLANE_H as H, PLANE_W as W  # noqa: E402
from gs2e.testing import plane_model, straight_trajectory  # noqa: E402


def test_subframe_rules():
    np.testing.assert_allclose(subframe_times_us(1000.0, 400.0, 4), [850, 950, 1050, 1150])
    assert subframes_needed(0.0, 1.0, 64) == 1
    assert subframes_needed(10.2, 1.0, 64) == 11
    assert subframes_needed(1e9, 1.0, 64) == 64
    img = np.random.default_rng(0).random((5, 5, 3))
    np.testing.assert_allclose(average_srgb([img, img, img]), img, atol=1e-12)
    # averaging happens in linear light: black + white is not mid-grey in sRGB
    mix = average_srgb([np.zeros((1, 1, 3)), np.ones((1, 1, 3))])
    assert mix[0, 0, 0] == pytest.approx(linear_to_srgb(0.5), abs=1e-12) and mix[0, 0, 0] > 0.7


def test_color_round_trip():
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(x)), x, atol=1e-12)


@pytest.fixture(scope="module")
def plane(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("plane")
    return plane_model(tmp), tmp


def test_static_camera_blur_equals_sharp(plane, tmp_path):
    from gs2e.render.dataset import render_dataset

    model, _ = plane
    traj = straight_trajectory(tmp_path, dx=1e-9)  # degenerate path: the camera does not move
    cfg = RenderSettings.defaults(fps=10.0, exposure_us=50_000.0, write_depth=False)
    render_dataset(model, traj, tmp_path / "out", cfg)
    import imageio.v3 as iio

    for f in sorted((tmp_path / "out" / "rgb").glob("*.png")):
        assert np.array_equal(iio.imread(f), iio.imread(tmp_path / "out" / "blur" / f.name))


def test_subframes_from_the_forward_renderer_are_the_sharp_renderers_image(plane, tmp_path):
    """Sub-frames come from the forward-only renderer: the same bits as the image of
    the full render (alpha, depth) at the same pose, clamped to [0, 1], in a buffer
    of their own (a kept sub-frame is not overwritten by the next render)."""
    from gs2e.render.renderer import TrajectoryRenderer

    model, _ = plane
    r = TrajectoryRenderer(model, straight_trajectory(tmp_path, dx=0.6), background=(0.2, 0.1, 0.0))
    first = None
    for t in np.linspace(r.t0_us, r.t1_us, 5):
        c2w = r.pose(float(t))
        sub = r.render_rgb(c2w)
        np.testing.assert_array_equal(sub.astype(np.float64), r.render_pose(c2w)[0])
        assert sub.min() >= 0.0 and sub.max() <= 1.0
        if first is None:
            first, kept = sub, sub.copy()
    np.testing.assert_array_equal(first, kept)
    assert r.renders == 10


def test_constant_velocity_pan_matches_box_filter(plane, tmp_path):
    """Blur of a fronto-parallel textured plane under constant-velocity
    translation = the sharp image box-filtered along x over the exposure's
    image motion (computed here independently by sub-pixel shifting)."""
    import cv2

    from gs2e.render.blur import average_srgb
    from gs2e.render.renderer import TrajectoryRenderer

    model, _ = plane
    traj = straight_trajectory(tmp_path, dx=0.6)
    r = TrajectoryRenderer(model, traj)
    t_mid = (r.t0_us + r.t1_us) // 2
    E = (r.t1_us - r.t0_us) * 0.4
    xa, xb = r.pose(t_mid - E / 2)[0, 3], r.pose(t_mid + E / 2)[0, 3]
    motion_px = F * (xb - xa) / DEPTH  # image shift over the exposure (camera +x -> image -x)
    assert 4 < motion_px < 40
    n = int(np.ceil(motion_px / 0.5))
    blur = average_srgb([r.render_at(t)[0] for t in subframe_times_us(t_mid, E, n)])
    sharp = srgb_to_linear(r.render_at(t_mid)[0])
    shifts = np.linspace(-motion_px / 2, motion_px / 2, 400)
    box = np.mean([cv2.warpAffine(sharp, np.float64([[1, 0, s], [0, 1, 0]]), (W, H),
                                  flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT) for s in shifts], axis=0)
    box = linear_to_srgb(box)
    m = int(np.ceil(motion_px / 2)) + 2
    err = np.abs(blur - box)[:, m:-m]
    ghost = np.abs(average_srgb([r.render_at(t)[0] for t in subframe_times_us(t_mid, E, 3)]) - box)[:, m:-m]
    assert err.mean() < 0.01 and np.percentile(err, 99) < 0.04
    assert ghost.mean() > 2 * err.mean(), "3 ghost copies should be clearly worse than true blur"


def test_dataset_records_round_trip(plane, tmp_path):
    import pandas as pd

    from gs2e.render.dataset import read_frames_table, render_dataset
    from gs2e.trajectory import load_trajectory

    model, _ = plane
    traj_path = straight_trajectory(tmp_path, dx=0.3)
    cfg = RenderSettings.defaults(fps=20.0, exposure_us=10_000.0)
    stats = render_dataset(model, traj_path, tmp_path / "out", cfg, scene_id="plane")
    df = read_frames_table(tmp_path / "out")
    tr = load_trajectory(traj_path)
    assert df["t_us"].dtype == np.int64 and np.all(np.diff(df["t_us"]) > 0)
    for _, row in df.iterrows():
        np.testing.assert_array_equal(row["c2w"], tr.pose_at(np.array([float(row["t_us"])]))[0])
    tj = json.loads((tmp_path / "out" / "transforms.json").read_text())
    assert len(tj["frames"]) == len(df) == stats["n_frames"]
    assert (tmp_path / "out" / "depth" / "000000.npz").exists()
    m = pd.read_parquet(tmp_path / "out" / "metrics.parquet")
    assert m.loc[0, "scene_id"] == "plane"


def test_exposure_longer_than_frame_interval_rejected(plane, tmp_path):
    from gs2e.render.dataset import render_dataset

    model, _ = plane
    traj = straight_trajectory(tmp_path, dx=0.3)
    # The config check rejects it before any job runs ...
    with pytest.raises(ConfigError, match="render.exposure_us"):
        load_config({"render": {"fps": 100.0, "exposure_us": 20_000.0}})
    # ... and so do the render stage's settings, however they are changed
    cfg = RenderSettings.defaults(fps=100.0, exposure_us=5_000.0)
    with pytest.raises(ConfigError, match="render.exposure_us"):
        render_dataset(model, traj, tmp_path / "out", cfg.replace(exposure_us=20_000.0))
    assert not (tmp_path / "out").exists()


def test_empty_view_rejected(plane, tmp_path):
    """A camera looking away from the model: clear error, no output."""
    from gs2e.render.dataset import render_dataset
    from gs2e.trajectory.io import save_trajectory
    from gs2e.trajectory.settings import TrajectorySettings
    from gs2e.trajectory.stage import generate

    model, _ = plane
    frames = []
    for i in range(4):
        T = np.eye(4)
        T[:3, :3] = np.diag([-1.0, 1.0, -1.0])  # turned around: looks at -z
        T[0, 3] = 0.1 * i
        frames.append(Frame(f"{i}.png", Camera(F, F, W / 2, H / 2), T))
    cfg_t = TrajectorySettings.defaults(speed_presets=["medium"], mini_groups=0, plot=False, view_order="sequence")
    tr = generate(Scene(W, H, frames, "t"), cfg_t, seed=0).trajectories["base_medium"]
    save_trajectory(tmp_path / "away.npz", tr)
    cfg = RenderSettings.defaults()
    with pytest.raises(InputError, match="empty"):
        render_dataset(model, tmp_path / "away.npz", tmp_path / "out", cfg)
    assert not (tmp_path / "out").exists()
