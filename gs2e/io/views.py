"""Views of a source scene before ingestion: where each image is, its camera
(for the image size the source declares) and its pose.

Source readers (COLMAP, NeRF transforms.json, plain folders) return lists of
:class:`SourceView`; :mod:`gs2e.io.ingest` reads the images, reconciles the
declared and actual sizes and writes the internal layout.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gs2e.io.scene import Camera

# Source layouts gs2e ingest reads (see gs2e.io.ingest).
LAYOUTS = ("demo", "internal", "folder", "colmap", "mvimgnet", "dl3dv", "nerf", "ecd", "llff", "projection")


@dataclass
class SourceView:
    """One view of a source scene.

    name: the image's name in the source (relative path as the source writes it).
    path: the image file on disk (may not exist; ingestion checks).
    camera: intrinsics in pixels for an image of ``size``; None = unknown.
    size: (W, H) in pixels that ``camera`` refers to; None = the actual image size.
    c2w: (4, 4) camera-to-world, OpenCV axes; None = no pose.
    """

    name: str
    path: Path
    camera: Camera | None = None
    size: tuple[int, int] | None = None
    c2w: np.ndarray | None = None


_DIGITS = re.compile(r"(\d+)")


def natural_key(name: str) -> tuple:
    """Sort key that orders embedded numbers numerically ('f2' < 'f10').

    For zero-padded names (COLMAP, MVImgNet, DL3DV) this is plain name order.
    """
    parts = _DIGITS.split(name)
    return tuple((0, int(p), p) if p.isdigit() else (1, p.lower(), p) for p in parts if p != "") \
        + ((2, name, name),)


def sort_views(views: list[SourceView]) -> list[SourceView]:
    """Views sorted by name (natural order)."""
    return sorted(views, key=lambda v: natural_key(v.name))
