"""Event-3DGS (lanpokn/Event-3DGS, ``scene/dataset_readers.py``
readColmapSceneInfo) layout::

    <scene>/sparse/0/{cameras,images,points3D}.bin  COLMAP model: PINHOLE camera, one
                                                    image per view (world-to-camera),
                                                    the SfM points (same world frame)
    <scene>/images/NNNNNN.png          intensity estimated from events (grey)
    <scene>/images_event/NNNNNN.png    the same estimate: consecutive images give the
                                       log-intensity change the events encode
    <scene>/images_blurry/NNNNNN.png   motion-blurred RGB frames (--deblur)
    <scene>/renders/NNNNNN.png         sharp RGB ground truth (test views)

File names match across folders and the COLMAP image names (the loader pairs
them by name and sorts views by name). The method has no event file: its
events enter as intensity images. ``event3dgs_intensity: integrate`` (default)
builds them by direct integration, the classical estimate: the first exported
frame's luminance is the anchor and each pixel's log signal moves by its
contrast threshold per event (ideal model: log(L + log_eps), per-pixel
thresholds of events.h5; DVS-Voltmeter: log(L * scale + k2) in the preset's
intensity unit, step theta / k1, its bright-pixel limit, leak ignored).
``sharp`` writes the rendered sharp frames in grey instead (an oracle
reconstruction, for upper-bound experiments).

Its train.py (--event) draws a view index in [2, N - 4] and pairs images
index and index + 1 (L116-118, L149-152), so image k - 1 to image k is
exactly gs2e's inter-frame window of frame k. It never draws the sorted
positions 5, 25, 45, 65, 85 (L128-131, "test on 5,25,45,65,85"; it takes
the view before): those are its held-out views (``heldout_frames`` in the
manifest; their images still enter as the second of the pair before them),
scored against renders/, which holds every view's sharp frame
(dataset_readers.py L176-179).
"""

from __future__ import annotations


import numpy as np

from gs2e.common.color import linear_to_srgb, luminance, srgb_to_linear
from gs2e.common.errors import InputError
from gs2e.events.models import MODELS
from gs2e.events.represent import event_frame
from gs2e.events.settings import read_settings
from gs2e.export.common import ExportOut
from gs2e.export.settings import ExportSettings

MIN_VIEWS = 7  # train.py L118: index = randint(2, len(views) - 4), and index + 1 (L152)
HELDOUT_POSITIONS = (5, 25, 45, 65, 85)  # train.py L128-131: never drawn as the training view


class LogSignal:
    """The event model's log signal G(L) of linear luminance L in [0, 1] and the
    per-pixel log steps of one ON / OFF event."""

    def __init__(self, attrs: dict, shape: tuple[int, int], where: str):
        model = attrs.get("model")
        th_on, th_off = attrs.get("theta/on"), attrs.get("theta/off")
        if th_on is None or th_off is None:
            raise InputError(f"{where}: no per-pixel thresholds theta/on, theta/off to integrate events")
        if model not in MODELS:
            raise InputError(f"{where}: unknown event model {model!r}")
        self.scale, self.offset, div = MODELS[model].log_signal_of(read_settings(attrs, where))
        self.step_on = np.asarray(th_on, np.float64) / div
        self.step_off = np.asarray(th_off, np.float64) / div
        if self.step_on.shape != shape:
            raise InputError(f"{where}: threshold maps are {self.step_on.shape}, frames {shape}")

    def G(self, lum: np.ndarray) -> np.ndarray:
        return np.log(np.asarray(lum, np.float64) * self.scale + self.offset)

    def inverse(self, g: np.ndarray) -> np.ndarray:
        return (np.exp(g) - self.offset) / self.scale


def integrated_intensity(src, frames: np.ndarray) -> list[np.ndarray]:
    """Linear luminance (H, W) per frame by direct event integration from the
    first frame's rendered luminance (see module docstring)."""
    from gs2e.events.io import read_h5

    _, attrs = read_h5(src.events_file, (0, 0))
    sig = LogSignal(attrs, (src.height, src.width), str(src.events_file))
    t = src.frames["t_us"].to_numpy()
    g = sig.G(luminance(srgb_to_linear(src.image("rgb", int(frames[0])) / 255.0)))
    out = [sig.inverse(g)]
    for a, b in zip(frames[:-1], frames[1:]):
        counts = event_frame(src.events(int(t[a]), int(t[b])), (src.height, src.width))
        g = g + counts[1] * sig.step_on - counts[0] * sig.step_off
        out.append(sig.inverse(g))
    return out


def grey_png(lum: np.ndarray) -> np.ndarray:
    """uint8 (H, W, 3) sRGB grey image of linear luminance (clipped to [0, 1])."""
    v = (linear_to_srgb(np.clip(lum, 0.0, 1.0)) * 255.0 + 0.5).astype(np.uint8)
    return np.repeat(v[..., None], 3, axis=2)


def export_event3dgs(src, out: ExportOut, cfg: ExportSettings) -> None:
    from gs2e.io.colmap import write_colmap_model
    from gs2e.io.scene import Camera, Frame, Scene

    frames = src.covered_frames()
    if len(frames) < MIN_VIEWS:
        raise InputError(f"{src.events_file}: events cover {len(frames)} frames; Event-3DGS's train.py "
                         f"needs at least {MIN_VIEWS} views")
    mode = cfg.event3dgs_intensity
    lum = (integrated_intensity(src, frames) if mode == "integrate"
           else [luminance(srgb_to_linear(src.image("rgb", int(i)) / 255.0)) for i in frames])
    has_blur = (src.frames["exposure_us"].to_numpy() > 0).all()
    names, scene_frames = [], []
    for k, i in enumerate(frames):
        name = f"{k:06d}.png"
        names.append(name)
        grey = grey_png(lum[k])
        out.png(f"images/{name}", grey)
        out.png(f"images_event/{name}", grey)
        out.png(f"renders/{name}", src.image("rgb", int(i)))
        if has_blur:
            out.png(f"images_blurry/{name}", src.image("blur", int(i)))
        K = src.K(int(i))
        scene_frames.append(Frame(name, Camera(K[0, 0], K[1, 1], K[0, 2], K[1, 2]), src.c2w([i])[0]))
    xyz, rgb = src.points()
    scene = Scene(src.width, src.height, scene_frames, "event3dgs",
                  points_xyz=xyz if len(xyz) else None, points_rgb=rgb if len(xyz) else None)
    if not len(xyz):
        out.warn("no SfM points: sparse/0/points3D.bin is empty (3DGS needs an initial point cloud)")
    write_colmap_model(scene, out.path("sparse/0"))
    if not has_blur:
        out.warn("no blurred frames (render.write_blur: false): images_blurry/ is not written")
    t = src.frames["t_us"].to_numpy()
    out.manifest.update({
        "target": "lanpokn/Event-3DGS scene/dataset_readers.py readColmapSceneInfo",
        "intensity": mode, "gs2e_frames": frames.tolist(), "images": names,
        "heldout_frames": [int(frames[k]) for k in HELDOUT_POSITIONS if k < len(frames)],
        "t_us": [int(t[i]) for i in frames],
        "n_events": int(sum(src.window_counts("inter", frames[1:]))),
        "poses": "sparse/0: COLMAP world-to-camera (OpenCV axes), gs2e world frame",
        "polarity": "events enter as intensity images: ON raises, OFF lowers the log signal",
    })
