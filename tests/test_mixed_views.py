"""A real phone capture of mixed orientation (../shared/data/mouse_colmap):
every view keeps its size and orientation through ingest, SfM, training and
evaluation, in both layouts that read it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gs2e.io.images import read_image
from gs2e.io.ingest import ingest_scene
from gs2e.io.scene import IMAGES_DIR, read_scene
from gs2e.io.settings import IngestSettings
from tests.conftest import shared_data


def _orientations(scene) -> list[str]:
    return ["portrait" if h > w else "landscape" for w, h in
            (scene.frame_size(i) for i in range(len(scene.frames)))]


@pytest.fixture(scope="module")
def mouse(tmp_path_factory):
    """mouse_colmap ingested (320 px: fast) in the colmap layout, and its SfM
    output from the capture's own cameras and points."""
    from gs2e.sfm.colmap_sfm import run_sfm
    from gs2e.sfm.settings import SfmSettings

    src = shared_data("mouse_colmap")
    root = tmp_path_factory.mktemp("mouse")
    scene = ingest_scene(src, "colmap", root / "ingest", IngestSettings.defaults(max_side=320))
    run_sfm(root / "ingest", root / "sfm", SfmSettings.defaults(reuse_poses=True), threads=2)
    return src, root, scene


def test_both_layouts_keep_each_views_orientation(mouse, tmp_path):
    import pycolmap

    src, root, scene = mouse
    rec = pycolmap.Reconstruction(str(src / "sparse" / "0") if (src / "sparse" / "0").is_dir()
                                  else str(src / "sparse"))
    truth = {im.name: ("portrait" if rec.cameras[im.camera_id].height > rec.cameras[im.camera_id].width
                       else "landscape") for im in rec.images.values() if im.has_pose}
    mv = ingest_scene(src, "mvimgnet", tmp_path / "mv", IngestSettings.defaults(max_side=320))
    for s, folder in ((scene, root / "ingest"), (mv, tmp_path / "mv")):
        orient = _orientations(s)
        names = s.extra["ingest"]["original_names"]
        assert orient == [truth[n] for n in names]
        assert 0 < orient.count("portrait") < orient.count("landscape")
        assert (s.width, s.height) == (320, 240)  # the most common view: landscape
        for i, f in enumerate(s.frames):
            w, h = s.frame_size(i)
            assert read_image(folder / IMAGES_DIR / f.name).shape == (h, w, 3)
            # the capture's own camera, scaled the same along both axes (not squeezed)
            c = rec.cameras[rec.find_image_with_name(names[i]).camera_id]
            fx, fy, cx, cy = c.params
            assert (c.width, c.height) == (6 * w, 6 * h)
            assert [f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy] == \
                pytest.approx([fx / 6, fy / 6, cx / 6, cy / 6], rel=1e-9)
    assert [f.camera for f in mv.frames] == [f.camera for f in scene.frames]
    assert mv.extra.get("sequential") is True


def test_sfm_training_and_evaluation_keep_each_views_size(mouse, tmp_path):
    from gs2e.splat.evaluate import render_views
    from gs2e.splat.settings import SplatSettings
    from gs2e.splat.train import train

    _, root, scene = mouse
    sfm = read_scene(root / "sfm")
    assert [sfm.frame_size(i) for i in range(len(sfm.frames))] == \
        [scene.frame_size(i) for i in range(len(scene.frames))]
    cfg = SplatSettings.defaults(max_iterations=30, min_iterations=0, eval_every=15, sh_degree=0,
                                 resolution_schedule=[[0, 2], [15, 1]], test_every=8)
    st = train(root / "sfm", tmp_path / "splat", cfg, threads=2, target_size=(160, 120))
    assert (st["train_width"], st["train_height"]) == (160, 120)
    sizes = json.loads((tmp_path / "splat" / "model.json").read_text())["view_sizes"]
    focal = {f.name: np.sqrt(f.camera.fx * f.camera.fy) for f in sfm.frames}
    f_ref = np.median([focal[sfm.frames[i].name] for i in sfm.main_frames()])
    for i, f in enumerate(sfm.frames):
        # orientation kept; every view at the angular resolution of a 160x120 main view
        # (this phone changes its focal length by up to 1.6x between shots)
        w, h = sfm.frame_size(i)
        tw, th = sizes[f.name]
        assert (tw > th) == (w > h)
        assert max(tw, th) == pytest.approx(min(1.0, 0.5 * f_ref / focal[f.name]) * max(w, h), abs=1.0)
    rows = render_views(tmp_path / "splat", root / "sfm", tmp_path / "views", "all")
    assert len(rows) == len(sfm.frames)
    for f in sfm.frames:
        img = read_image(tmp_path / "views" / (f.name.rsplit(".", 1)[0] + ".png"))
        assert img.shape[:2] == tuple(sizes[f.name])[::-1]
    # a view whose stored image disagrees with scene.json is refused, not squeezed
    from gs2e.common.errors import InputError
    from gs2e.splat.views import load_views

    sfm.extra["frame_sizes"] = [[240, 320]] * len(sfm.frames)
    with pytest.raises(InputError, match="is 320x240 but .*scene.json says 240x320"):
        load_views(root / "sfm", sfm, [1])
