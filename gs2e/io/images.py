"""Image files: read as 8-bit RGB, write PNG, resize with matching intrinsics.

Images in gs2e are numpy arrays of shape (H, W, 3), dtype uint8, RGB order.
Pixel centres are at integer + 0.5 (see :mod:`gs2e.io.scene`), so resizing an
image from (W, H) to (W', H') scales every continuous image coordinate, and the
intrinsics, by exactly (W'/W, H'/H).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np

from gs2e.common.camera import fit_scale
from gs2e.common.errors import InputError
from gs2e.io.scene import Camera

IMAGE_EXTS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".webp", ".ppm", ".pgm")
# PNG zlib level and row filter: fixed so the same pixels give the same bytes.
# The Paeth filter on every row instead of libpng's per-row choice among all
# five: 1.1-1.6x faster to encode, files within 3 % of the size (photos of
# 255 to 1920 px; measured 2026-11-28). OpenCV before 4.11 has no such flag.
PNG_COMPRESSION = 3
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]
if hasattr(cv2, "IMWRITE_PNG_FILTER"):
    _PNG_PARAMS += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_PAETH]


def is_image_file(path: str | os.PathLike, exts: tuple[str, ...] = IMAGE_EXTS) -> bool:
    """True for a regular, not hidden file whose extension is in ``exts``
    (hidden files, e.g. macOS '._0001.png' or a killed job's temporaries, are
    not frames)."""
    p = Path(path)
    return p.suffix.lower() in exts and not p.name.startswith(".") and p.is_file()


def list_images(folder: str | os.PathLike, exts: tuple[str, ...] = IMAGE_EXTS) -> list[Path]:
    """The image files of ``folder`` in natural name order (frame2 before
    frame10, as people number frames), the one order every gs2e stage uses."""
    from gs2e.io.views import natural_key

    return sorted((p for p in Path(folder).iterdir() if is_image_file(p, exts)),
                  key=lambda p: natural_key(p.name))


def decode_image(data: bytes, name: str = "image") -> np.ndarray:
    """Decode encoded image bytes to uint8 RGB (H, W, 3).

    16-bit images are rounded to 8 bits (v / 257), float images are taken as
    [0, 1], grayscale is replicated to RGB and an alpha channel is dropped.
    The stored pixel grid is returned: ingest applies EXIF orientation
    (:func:`exif_orientation`, :func:`apply_orientation`) where it belongs.
    Raises InputError naming ``name`` when the bytes are empty or undecodable.
    """
    if len(data) == 0:
        raise InputError(f"image file {name} is empty (0 bytes)")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise InputError(f"image file {name} is corrupt or not a supported image format")
    if img.dtype == np.uint16:
        img = ((img.astype(np.uint32) + 128) // 257).astype(np.uint8)
    elif img.dtype in (np.float32, np.float64):
        if not np.all(np.isfinite(img)):
            raise InputError(f"image file {name} contains NaN or inf pixels")
        img = np.clip(np.rint(img * 255.0), 0, 255).astype(np.uint8)
    elif img.dtype != np.uint8:
        raise InputError(f"image file {name} has unsupported pixel type {img.dtype}")
    if img.ndim == 2:
        img = img[:, :, None]
    ch = img.shape[2]
    if ch in (1, 2):  # gray or gray+alpha
        rgb = np.repeat(img[:, :, :1], 3, axis=2)
    elif ch in (3, 4):  # BGR or BGRA
        rgb = img[:, :, 2::-1]
    else:
        raise InputError(f"image file {name} has {ch} channels (expected 1-4)")
    return np.ascontiguousarray(rgb)


def read_image_bytes(path: str | os.PathLike) -> bytes:
    """Raw bytes of an image file; InputError naming the file if missing/unreadable."""
    p = Path(path)
    if not p.exists():
        raise InputError(f"image file {p} does not exist")
    if not p.is_file():
        raise InputError(f"image path {p} is not a file")
    try:
        return p.read_bytes()
    except OSError as exc:
        raise InputError(f"cannot read image file {p}: {exc.strerror or exc}") from exc


def check_image_size(path: str | os.PathLike) -> None:
    """InputError naming ``path`` when its header declares a pixel array beyond
    gs2e's limit (:func:`gs2e.common.camera.size_problem`): read from the header
    (Pillow opens lazily), before a decoder allocates the image. Files Pillow
    cannot parse are left to the decoder's own error."""
    from PIL import Image, UnidentifiedImageError

    from gs2e.common.camera import size_problem

    Image.MAX_IMAGE_PIXELS = None  # the limit is gs2e's, checked below
    try:
        with Image.open(path) as im:
            w, h = im.size
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return
    why = size_problem(int(w), int(h))
    if why:
        raise InputError(f"image file {path}: its size {why}")


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """(width, height) of an image file's stored pixel grid, from its header
    (Pillow opens lazily; a file Pillow cannot parse is decoded). InputError
    naming the file when it is missing or unreadable."""
    from PIL import Image, UnidentifiedImageError

    Image.MAX_IMAGE_PIXELS = None  # gs2e's own limit: check_image_size
    try:
        with Image.open(path) as im:
            return int(im.size[0]), int(im.size[1])
    except (UnidentifiedImageError, ValueError, SyntaxError):
        img = read_image(path)
        return img.shape[1], img.shape[0]
    except OSError:
        read_image_bytes(path)  # the one-line error for a missing or unreadable file
        raise


EXIF_ORIENTATION_TAG = 0x0112


def exif_orientation(path: str | os.PathLike) -> int:
    """The EXIF Orientation (1-8) of an image file; 1 (as stored) when the
    file has none or Pillow cannot read it."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            o = im.getexif().get(EXIF_ORIENTATION_TAG, 1)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return 1
    return int(o) if isinstance(o, int) and 1 <= o <= 8 else 1


def apply_orientation(img: np.ndarray, orientation: int) -> np.ndarray:
    """``img`` (H, W, ...) as a viewer shows it under EXIF Orientation 1-8
    (the transposes of Pillow's ``ImageOps.exif_transpose``; tested against
    it): 2 mirror, 3 rotate 180, 4 flip, 5 transpose, 6 rotate 90 clockwise,
    7 transverse, 8 rotate 90 counter-clockwise."""
    t = (1, 0) + tuple(range(2, img.ndim))
    ops = {1: lambda a: a, 2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.transpose(t), 6: lambda a: np.rot90(a, -1), 7: lambda a: a.transpose(t)[::-1, ::-1],
           8: lambda a: np.rot90(a, 1)}
    return np.ascontiguousarray(ops[int(orientation)](img))


def upright_size(size: tuple[int, int], orientation: int) -> tuple[int, int]:
    """(W, H) of a stored (W, H) image once its EXIF orientation is applied."""
    return (size[1], size[0]) if orientation in (5, 6, 7, 8) else tuple(size)


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as uint8 RGB (H, W, 3); InputError naming the file on failure."""
    return decode_image(read_image_bytes(path), str(path))


def to_u8(img01: np.ndarray) -> np.ndarray:
    """uint8 of an image in [0, 1] (clipped, rounded half up): how rendered
    frames are written."""
    return (np.clip(img01, 0, 1) * 255 + 0.5).astype(np.uint8)


def encode_png(rgb: np.ndarray, params: list[int] | None = None) -> bytes:
    """PNG bytes of a uint8 or uint16 RGB (H, W, 3) image (deterministic for
    given pixels; uint16 writes a 16-bit PNG, as DSEC's optical flow);
    ``params``: OpenCV's PNG flags instead of the default level and filter."""
    rgb = np.asarray(rgb)
    if rgb.dtype not in (np.uint8, np.uint16) or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected uint8 or uint16 (H, W, 3), got {rgb.dtype} {rgb.shape}")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(rgb[:, :, ::-1]),
                           _PNG_PARAMS if params is None else params)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return buf.tobytes()


def write_png(path: str | os.PathLike, rgb: np.ndarray, params: list[int] | None = None) -> None:
    """Write uint8 or uint16 RGB (H, W, 3) as PNG (callers write into an
    atomic_dir); ``params`` as :func:`encode_png`'s."""
    Path(path).write_bytes(encode_png(rgb, params))


def scaled_size(width: int, height: int, downscale: int = 1,
                max_side: int | None = None) -> tuple[int, int]:
    """Output (W, H) after an integer ``downscale`` and then a cap on the longer side.

    Both steps round to the nearest integer pixel count (at least 1).
    """
    if downscale < 1:
        raise ValueError("downscale must be >= 1")
    w = max(1, int(math.floor(width / downscale + 0.5)))
    h = max(1, int(math.floor(height / downscale + 0.5)))
    if max_side is not None and max(w, h) > max_side:
        s = max_side / max(w, h)
        w = max(1, min(max_side, int(math.floor(w * s + 0.5))))
        h = max(1, min(max_side, int(math.floor(h * s + 0.5))))
    return w, h


def cover_max_side(width: int, height: int, target: tuple[int, int] | None) -> int | None:
    """The smallest longer side at which a (width, height) image, scaled
    uniformly, still covers a target (W, H) image at scale >= 1 (what a camera
    fitted with ``cover`` renders from it); None when that needs the full size
    or there is no target."""
    if target is None:
        return None
    side = int(math.ceil(fit_scale(width, height, *target, "cover") * max(width, height)))
    return None if side >= max(width, height) else max(16, side)


def resize_image(rgb: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Resize (H, W, 3) to ``size`` = (W', H'): area filter when shrinking,
    bilinear when enlarging. Returns the input unchanged if the size matches."""
    w, h = size
    if rgb.shape[1] == w and rgb.shape[0] == h:
        return rgb
    shrink = w <= rgb.shape[1] and h <= rgb.shape[0]
    interp = cv2.INTER_AREA if shrink else cv2.INTER_LINEAR
    return cv2.resize(rgb, (int(w), int(h)), interpolation=interp)


def resize_with_camera(rgb: np.ndarray, camera: Camera,
                       size: tuple[int, int]) -> tuple[np.ndarray, Camera, tuple[float, float]]:
    """Resize an image to ``size`` = (W', H') and scale its intrinsics to match.

    Returns (image, camera, (sx, sy)) with sx = W'/W, sy = H'/H.
    """
    h0, w0 = rgb.shape[:2]
    sx, sy = size[0] / w0, size[1] / h0
    if sx == 1.0 and sy == 1.0:
        return rgb, camera, (1.0, 1.0)
    return resize_image(rgb, size), camera.scaled(sx, sy), (sx, sy)
