"""Real recordings with real frames, for the benchmark's real-data rows.

Each reader returns a :class:`Recording`: the events, the sensor size, and the
sensor's own APS frames with their times, the ground truth of video
reconstruction on real data. Two layouts are read:

* an ECD sequence folder (Mueller et al., IJRR 2017): ``events.txt``
  (``t_s x y p``, p 1 = ON) and ``images.txt`` (``t_s path`` per APS frame),
  e.g. ``../shared/data/slider_depth``; frames after the last event are left out;
* an AEDAT4 file with a frame stream (a DAVIS), e.g.
  ``../shared/data/events/davis346_street_aps.aedat4``; a frame's time is the
  middle of its exposure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gs2e.common.errors import InputError
from gs2e.events.models import Events


@dataclass(frozen=True)
class Recording:
    """``events`` time-sorted (t in us); ``shape`` (H, W) px; ``t_us`` (N,)
    int64 APS frame times; ``frames`` (N, H, W) float64 APS values in [0, 1]."""

    name: str
    events: Events
    shape: tuple[int, int]
    t_us: np.ndarray
    frames: np.ndarray


def aps_grey(img: np.ndarray) -> np.ndarray:
    """(H, W) float64 in [0, 1] of an 8- or 16-bit grey (or grey-as-RGB) frame."""
    img = np.asarray(img)
    full = 65535.0 if img.dtype == np.uint16 else 255.0
    if img.ndim == 3:
        img = img[..., 0]  # the APS is grey: its channels are equal
    return img.astype(np.float64) / full


def read_ecd(folder: str | Path) -> Recording:
    """An ECD sequence folder (``events.txt``, ``images.txt`` + frames)."""
    from gs2e.io.images import read_image

    root = Path(folder)
    for f in ("events.txt", "images.txt"):
        if not (root / f).is_file():
            raise InputError(f"{root / f} does not exist (an ECD sequence folder has events.txt and images.txt)")
    raw = np.loadtxt(root / "events.txt", ndmin=2)
    if raw.shape[1] != 4 or not len(raw):
        raise InputError(f"{root / 'events.txt'}: expected rows 't_s x y p', got shape {raw.shape}")
    ev = Events(np.round(raw[:, 0] * 1e6).astype(np.int64), raw[:, 1].astype(np.uint16),
                raw[:, 2].astype(np.uint16), raw[:, 3].astype(np.uint8))
    if np.any(np.diff(ev.t) < 0):
        raise InputError(f"{root / 'events.txt'}: timestamps are not sorted")
    rows = [ln.split() for ln in (root / "images.txt").read_text().splitlines()
            if ln.strip() and not ln.startswith("#")]
    t_us = np.array([round(float(r[0]) * 1e6) for r in rows], np.int64)
    keep = t_us <= ev.t[-1]  # the frames the events cover
    if keep.sum() < 2:
        raise InputError(f"{root}: fewer than two APS frames within the events' span")
    frames = np.stack([aps_grey(read_image(root / r[1])) for r, k in zip(rows, keep) if k])
    return Recording(root.name, ev, frames.shape[1:], t_us[keep], frames)


def read_aedat4_frames(path: str | Path) -> Recording:
    """An AEDAT4 recording with events and APS frames."""
    import faery

    from gs2e.events.io import read_events

    path = Path(path)
    ev, _ = read_events(path)
    t_us, frames = [], []
    for track, packet in faery.aedat.Decoder(path):
        if track.data_type == "frame":
            t_us.append((int(packet.exposure_start_t) + int(packet.exposure_end_t)) // 2)
            frames.append(aps_grey(np.asarray(packet.pixels)))
    if len(frames) < 2:
        raise InputError(f"{path}: {len(frames)} APS frames; video reconstruction needs two or more")
    return Recording(path.stem, ev, frames[0].shape, np.asarray(t_us, np.int64), np.stack(frames))


def read_recording(path: str | Path) -> Recording:
    """:func:`read_ecd` for a folder, :func:`read_aedat4_frames` for a ``.aedat4`` file."""
    p = Path(path)
    if p.is_dir():
        return read_ecd(p)
    if p.suffix == ".aedat4" and p.is_file():
        return read_aedat4_frames(p)
    raise InputError(f"{p}: not an ECD sequence folder or an .aedat4 file with frames")
