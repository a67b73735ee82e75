"""EXIF orientation, applied the same way in every layout (a phone's
Orientation = 6 JPEGs were ingested sideways without a word), except where
a view's given camera says its poses were made on the stored pixel grid."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image, ImageOps

from gs2e.io.images import EXIF_ORIENTATION_TAG, apply_orientation, exif_orientation, read_image
from gs2e.io.settings import IngestSettings


def _jpeg(path, rgb, orientation):
    im = Image.fromarray(rgb)
    exif = im.getexif()
    exif[EXIF_ORIENTATION_TAG] = orientation
    im.save(path, quality=100, exif=exif.tobytes())
    return path


@pytest.mark.parametrize("o", range(1, 9))
def test_orientations_match_pillow(o):
    rgb = np.random.default_rng(o).integers(0, 255, (5, 8, 3), dtype=np.uint8)
    im = Image.fromarray(rgb)
    exif = im.getexif()
    exif[EXIF_ORIENTATION_TAG] = o
    buf = io.BytesIO()
    im.save(buf, format="PNG", exif=exif.tobytes())
    ref = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(buf.getvalue()))))
    assert np.array_equal(apply_orientation(rgb, o), ref)


def test_folder_of_rotated_phone_photos_is_ingested_upright(tmp_path):
    from gs2e.io.ingest import ingest_scene

    src = tmp_path / "photos"
    src.mkdir()
    rng = np.random.default_rng(0)
    stored = []
    for i in range(3):
        rgb = (rng.integers(0, 255, (6, 8, 3)).repeat(10, 0).repeat(10, 1)).astype(np.uint8)  # 80 x 60 stored
        stored.append(rgb)
        _jpeg(src / f"p{i}.jpg", rgb, 6)
    assert exif_orientation(src / "p0.jpg") == 6
    scene = ingest_scene(src, "folder", tmp_path / "ingest", IngestSettings.defaults(max_side=None))
    assert (scene.width, scene.height) == (60, 80)  # portrait, as the phone showed it
    out = read_image(tmp_path / "ingest" / "images" / scene.frames[0].name)
    up, wrong = apply_orientation(stored[0], 6), apply_orientation(stored[0], 8)
    err = lambda ref: np.abs(out.astype(int) - ref).mean()  # noqa: E731  (JPEG's loss, ~5 levels)
    assert out.shape == up.shape and err(up) < err(wrong) / 5
    assert len(scene.extra["ingest"]["exif_orientation"]["applied"]) == 3


def test_views_with_cameras_for_the_stored_grid_are_kept(tmp_path):
    """A COLMAP project whose cameras are for the stored (landscape) grid:
    the poses were made on it, so the images stay as stored."""
    from gs2e.io.ingest import _upright
    from gs2e.io.scene import Camera
    from gs2e.io.views import SourceView

    rgb = np.zeros((60, 80, 3), np.uint8)
    path = _jpeg(tmp_path / "a.jpg", rgb, 6)
    exif = {"applied": [], "kept_stored": [], "ambiguous": []}
    cam = Camera(70.0, 70.0, 40.0, 30.0)
    kept = _upright(rgb, SourceView("a.jpg", path, cam, (80, 60), np.eye(4)), exif)
    assert kept.shape == (60, 80, 3) and exif["kept_stored"] == ["a.jpg"]
    turned = _upright(rgb, SourceView("a.jpg", path, Camera(70.0, 70.0, 30.0, 40.0), (60, 80), np.eye(4)), exif)
    assert turned.shape == (80, 60, 3) and exif["applied"] == ["a.jpg"]
    flipped = _upright(rgb, SourceView("b.jpg", _jpeg(tmp_path / "b.jpg", rgb, 3), cam, (80, 60), np.eye(4)),
                       exif)
    assert flipped.shape == (60, 80, 3) and exif["ambiguous"] == ["b.jpg"]
