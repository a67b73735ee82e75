"""Photographs bundled with scikit-image, turned into a texture atlas.

Only images that ship inside the scikit-image wheel are used (no pooch
download, so the demo works offline). Each photo is centre-cropped to a square,
resized to ``size`` x ``size`` texels, contrast-stretched and stored as float32
RGB in [0, 1]. Grey photos get their colour from a per-patch tint.

A *patch* is a window of one atlas texture (offset and size in texels, a tint,
a quarter-turn rotation); every surface element of the demo world refers to
one patch, and :meth:`Atlas.lookup` samples patches bilinearly.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from gs2e.common.errors import InputError

# Photos bundled in the scikit-image distribution (skimage/data/*.png|jpg in 0.26).
COLOUR_PHOTOS = ("astronaut", "coffee", "chelsea", "rocket", "immunohistochemistry",
                 "hubble_deep_field")
GREY_PHOTOS = ("brick", "grass", "gravel", "camera", "coins", "moon", "page", "text")
BUNDLED_PHOTOS = COLOUR_PHOTOS + GREY_PHOTOS
# Natural tints for grey photos (RGB multipliers): sand, moss, terracotta, slate,
# ochre, stone, plum.
TINTS = ((0.93, 0.82, 0.62), (0.55, 0.68, 0.42), (0.85, 0.52, 0.38), (0.55, 0.62, 0.72),
         (0.88, 0.72, 0.35), (0.80, 0.78, 0.74), (0.62, 0.50, 0.62))


def load_photo(name: str) -> np.ndarray:
    """One bundled scikit-image photo as uint8 (H, W, 3) RGB."""
    import skimage.data

    if name not in BUNDLED_PHOTOS:
        raise InputError(f"'{name}' is not one of the bundled demo photos {BUNDLED_PHOTOS}")
    try:
        img = np.asarray(getattr(skimage.data, name)())
    except Exception as exc:  # missing file in a broken install
        raise InputError(f"cannot load scikit-image photo '{name}': {exc}") from exc
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    return np.ascontiguousarray(img[:, :, :3]).astype(np.uint8)


def square_texture(img: np.ndarray, size: int) -> np.ndarray:
    """Centre square crop, resized (Lanczos) to (size, size, 3) float32 in [0, 1],
    contrast-stretched so the 1st..99th percentiles span [0.04, 0.96]."""
    from PIL import Image

    h, w = img.shape[:2]
    s = min(h, w)
    y0, x0 = (h - s) // 2, (w - s) // 2
    crop = Image.fromarray(img[y0:y0 + s, x0:x0 + s])
    if s != size:
        crop = crop.resize((size, size), Image.Resampling.LANCZOS)
    tex = np.asarray(crop, dtype=np.float32) / 255.0
    lo, hi = np.percentile(tex, [1.0, 99.0])
    if hi - lo > 1e-3:  # stretch dull photos (hubble) so SIFT finds structure
        tex = 0.04 + 0.92 * (tex - lo) / (hi - lo)
    return np.clip(tex, 0.0, 1.0).astype(np.float32)


@dataclass
class Atlas:
    """Stack of square textures plus a table of patches (windows into them)."""

    tex: np.ndarray                     # (K, S, S, 3) float32 in [0, 1]
    names: list[str]
    patch_k: list[int] = field(default_factory=list)
    patch_win: list[tuple[float, float, float, float]] = field(default_factory=list)  # ox, oy, sx, sy texels
    patch_tint: list[tuple[float, float, float]] = field(default_factory=list)
    patch_rot: list[int] = field(default_factory=list)
    _tables: tuple | None = None

    @property
    def size(self) -> int:
        return int(self.tex.shape[1])

    def index(self, name: str) -> int:
        return self.names.index(name)

    def add_patch(self, name: str, win: tuple[float, float, float, float] | None = None,
                  tint: tuple[float, float, float] = (1.0, 1.0, 1.0), rot: int = 0) -> int:
        """Register a window (ox, oy, sx, sy in texels; None = whole texture) of
        texture ``name``; returns the patch id."""
        S = float(self.size)
        self.patch_k.append(self.index(name))
        self.patch_win.append(tuple(map(float, win)) if win is not None else (0.0, 0.0, S, S))
        self.patch_tint.append(tuple(map(float, tint)))
        self.patch_rot.append(int(rot) % 4)
        self._tables = None
        return len(self.patch_k) - 1

    def random_patch(self, rng: np.random.Generator, pool: tuple[str, ...], win_px: tuple[float, float],
                     tint_grey: bool = True, rotate: bool = False) -> int:
        """A patch of a random photo of ``pool`` at a random offset; grey photos get a random tint."""
        name = pool[int(rng.integers(len(pool)))]
        sx, sy = (min(float(w), self.size) for w in win_px)
        ox = float(rng.uniform(0, self.size - sx))
        oy = float(rng.uniform(0, self.size - sy))
        tint = (1.0, 1.0, 1.0)
        if tint_grey and name in GREY_PHOTOS:
            base = np.asarray(TINTS[int(rng.integers(len(TINTS)))])
            tint = tuple(float(c) for c in np.clip(base * rng.uniform(0.85, 1.08), 0, 1))
        rot = int(rng.integers(4)) if rotate else 0
        return self.add_patch(name, (ox, oy, sx, sy), tint, rot)

    def _arrays(self):
        if self._tables is None:
            win = np.asarray(self.patch_win, np.float32).reshape(-1, 4)
            K, S = self.tex.shape[:2]
            # RGB padded to 4 floats: np.take of 16-byte rows is the fastest gather
            texels = np.zeros((K * S * S, 4), np.float32)
            texels[:, :3] = self.tex.reshape(-1, 3)
            self._tables = (np.asarray(self.patch_k, np.int64), win,
                            np.asarray(self.patch_tint, np.float32).reshape(-1, 3),
                            np.asarray(self.patch_rot, np.int8), texels)
        return self._tables

    def lookup(self, pid: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Bilinear colour of patches ``pid`` (N,) at patch coordinates u, v in [0, 1]
        (u to the right, v down the photo). Returns (3, N) float32 in [0, 1]."""
        k, win, tint, rot, texels = self._arrays()
        pid = np.asarray(pid, np.int64)
        u = np.asarray(u, np.float32)
        v = np.asarray(v, np.float32)
        r = rot[pid]
        if r.any():  # quarter turns of the patch
            u, v = (np.where(r == 0, u, np.where(r == 1, v, np.where(r == 2, 1 - u, 1 - v))),
                    np.where(r == 0, v, np.where(r == 1, 1 - u, np.where(r == 2, 1 - v, u))))
        w = win[pid].T
        S = self.size
        # texel centres at integer + 0.5
        x = w[0] + np.clip(u, 0, 1) * w[2] - np.float32(0.5)
        y = w[1] + np.clip(v, 0, 1) * w[3] - np.float32(0.5)
        x0f = np.floor(x)
        y0f = np.floor(y)
        fx = (x - x0f)[:, None]
        fy = (y - y0f)[:, None]
        xi = x0f.astype(np.int64)
        yi = y0f.astype(np.int64)
        x0 = np.clip(xi, 0, S - 1)  # clamp to the texture edge
        x1 = np.clip(xi + 1, 0, S - 1)
        base = k[pid] * (S * S)
        r0 = base + np.clip(yi, 0, S - 1) * S
        r1 = base + np.clip(yi + 1, 0, S - 1) * S
        top = np.take(texels, r0 + x0, axis=0)
        top += (np.take(texels, r0 + x1, axis=0) - top) * fx
        bot = np.take(texels, r1 + x0, axis=0)
        bot += (np.take(texels, r1 + x1, axis=0) - bot) * fx
        top += (bot - top) * fy
        return top[:, :3].T * tint[pid].T


def build_atlas(names: tuple[str, ...] = BUNDLED_PHOTOS, size: int = 256) -> Atlas:
    """Load the bundled photos ``names`` into an :class:`Atlas` of size x size textures."""
    tex = np.stack([square_texture(load_photo(n), size) for n in names])
    return Atlas(tex=tex, names=list(names))
