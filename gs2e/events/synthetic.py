"""Synthetic frame sources for tests and benchmarks."""

from __future__ import annotations

from typing import Iterator

import numpy as np

from gs2e.common.color import srgb_to_linear


def standard_sequence(n_frames: int = 480, fps: float = 2400.0, width: int = 346,
                      height: int = 260, t0_us: int = 0,
                      pan_px_per_s: float = 2300.0, zoom_per_s: float = 2.0
                      ) -> Iterator[tuple[int, np.ndarray]]:
    """The benchmark's standard sequence: scikit-image's astronaut photo in
    grey (linear luminance), panning right/down and zooming in.

    Yields (t_us int64, float32 (height, width) linear luminance in [0, 1]).
    At the defaults (0.2 s) the view pans by 460 photo pixels (~1.3-2 image
    pixels per frame) and zooms by 40 %; with the dvs346 preset this gives
    ~10 M events, like the sequence the public DVS-Voltmeter code was timed on
    (10.7 M events, REFERENCE.md section 2).
    Timestamps are rounded to integer microseconds.
    """
    import cv2
    from skimage import color, data

    img = srgb_to_linear(color.rgb2gray(data.astronaut())).astype(np.float32)  # 512x512
    sh, sw = img.shape
    cx0, cy0 = sw * 0.35, sh * 0.4
    for i in range(n_frames):
        t = i / fps
        zoom = 1.0 + zoom_per_s * t
        cx = cx0 + pan_px_per_s * t * 0.8
        cy = cy0 + pan_px_per_s * t * 0.6
        # dst = s * (src - c) + (w/2, h/2), s = zoom * base scale (crop ~ 60 % of the photo)
        s = zoom * width / (0.6 * sw)
        M = np.array([[s, 0, width / 2 - s * cx], [0, s, height / 2 - s * cy]], np.float64)
        frame = cv2.warpAffine(img, M, (width, height), flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)
        yield t0_us + int(round(t * 1e6)), np.clip(frame, 0.0, 1.0)
