"""Ingestion: read a scene in one of the source layouts and write the internal layout.

Layouts (``src`` is a folder unless said otherwise):

``demo`` / ``internal``
    An internal-layout folder (scene.json + images/ [+ points3d.npz]), e.g. the
    output of ``gs2e demo-scene``.
``folder``
    Plain images (in ``src`` or ``src/images``), sorted by name; no poses. The
    intrinsics are a PINHOLE guess fx = fy = 1.2 max(W, H), principal point at
    the image centre, flagged ``extra["intrinsics_guess"] = True``.
``colmap``
    ``images/`` + a sparse model in ``sparse/0`` or ``sparse`` (.bin or .txt).
    Only registered images become views; other images in ``images/`` are listed
    in the provenance.
``mvimgnet``
    An MVImgNet clip: the same files as ``colmap``; frames are video-ordered,
    ``extra["sequential"] = True``.
``dl3dv``
    A DL3DV scene: ``images_N/`` folders and a nerfstudio ``transforms.json``
    (in ``src`` or ``src/nerfstudio``) whose ``file_path`` points to
    ``images/<file>``; images are matched by file name (or stem). Reads ``images_subdir`` (or
    picks a folder: the largest, or the smallest still >= ``max_side``);
    intrinsics are scaled to the actual image size. If a COLMAP model exists
    under ``colmap/`` its points are aligned to the json poses (similarity fit
    on the camera centres) and kept (also ``src/colmap`` or
    ``src/gaussian_splat``, as in the DL3DV benchmark release).
    ``extra["sequential"] = True``.
``nerf``
    ``transforms.json`` (or ``transforms_train.json``) of NeRF synthetic /
    instant-ngp / nerfstudio; ``src`` may also be the json file itself.
``ecd``
    An Event Camera Dataset sequence folder (``images.txt``, ``groundtruth.txt``,
    ``calib.txt``; :mod:`gs2e.io.ecd`): the calibrated, distorted camera and
    each frame's pose interpolated at its time; frames outside the ground
    truth's span are left out. ``extra["sequential"] = True``.

Every layout goes through the same steps: sort views by name (natural order),
subsample to ``max_views`` evenly spaced views (first and last kept), read each
image (missing, empty, corrupt -> InputError naming the file), reconcile the
size the source's intrinsics refer to with the actual size, keep each view's
size and orientation (sizes other than the first view's or its rotation need
``allow_mixed_resolutions``), reject duplicate views (pixel-identical images),
downscale, re-encode as PNG and write the internal layout atomically. Provenance goes to ``extra["ingest"]``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from gs2e.common.atomic import atomic_dir
from gs2e.common.errors import ConfigError, InputError
from gs2e.common.log import timed
from gs2e.common.progress import progress
from gs2e.common.settings import require
from gs2e.io import colmap as colmap_io
from gs2e.io import nerf as nerf_io
from gs2e.io.images import (IMAGE_EXTS, apply_orientation, check_image_size, decode_image, exif_orientation,
                            is_image_file, list_images, read_image_bytes, upright_size,
                            resize_with_camera, scaled_size, write_png)
from gs2e.io.scene import (IMAGES_DIR, SCENE_JSON, Camera, Frame, Scene, main_size, read_scene,
                           with_frame_sizes, write_scene_json)
from gs2e.io.settings import IngestSettings
from gs2e.io.views import LAYOUTS, SourceView, natural_key, sort_views

log = logging.getLogger("gs2e.ingest")

GUESS_FOCAL_FACTOR = 1.2  # folder layout: fx = fy = 1.2 * max(W, H)
ASPECT_TOL = 0.02
# max_side: auto caps the longer side here: COLMAP's usual SIFT extraction limit
# (SiftExtractionOptions.max_image_size in its command line tools), so structure
# from motion sees what it would see from the photos, whatever the event sensor
SFM_MAX_SIDE = 3200  # relative aspect-ratio mismatch tolerated between declared and actual size


# ---------------------------------------------------------------- small pure helpers

def subsample_indices(n: int, max_views: int | None) -> np.ndarray:
    """Indices of ``max_views`` views evenly spaced over ``n`` (first and last kept).

    Deterministic: index_k = floor(k (n-1)/(m-1) + 0.5); strictly increasing
    because the spacing is >= 1. ``max_views`` None or >= n keeps all.
    """
    if max_views is None or max_views >= n:
        return np.arange(n)
    if max_views < 1:
        raise ValueError("max_views must be >= 1")
    if max_views == 1:
        return np.array([0])
    k = np.arange(max_views)
    return np.floor(k * (n - 1) / (max_views - 1) + 0.5).astype(np.int64)


def guess_camera(width: int, height: int) -> Camera:
    """PINHOLE guess for images without intrinsics: fx = fy = 1.2 max(W, H), centred."""
    f = GUESS_FOCAL_FACTOR * max(width, height)
    return Camera(f, f, width / 2.0, height / 2.0, "PINHOLE", [])


def unique_png_names(names: list[str]) -> list[str]:
    """Output PNG names: the source file's stem + .png; clashes (same stem in
    different folders or with different extensions) get the relative folder
    path joined with '_' and, if still needed, a numeric suffix."""
    stems = [Path(n).stem for n in names]
    out: list[str] = []
    used: set[str] = set()
    counts: dict[str, int] = {}
    for s in stems:
        counts[s] = counts.get(s, 0) + 1
    for n, s in zip(names, stems):
        cand = s if counts[s] == 1 else re.sub(r"[^A-Za-z0-9._-]+", "_",
                                                str(Path(n).with_suffix("")).strip("./")) or s
        if counts[s] > 1 and Path(n).suffix:
            cand = f"{cand}_{Path(n).suffix.lstrip('.').lower()}"
        base, i = cand, 1
        while cand + ".png" in used:
            cand = f"{base}_{i}"
            i += 1
        used.add(cand + ".png")
        out.append(cand + ".png")
    return out


# ---------------------------------------------------------------- layout readers

class _Source:
    """What a layout reader found: views in sequence order plus scene data."""

    def __init__(self, views: list[SourceView], points=(None, None), extra: dict | None = None,
                 provenance: dict | None = None):
        self.views = views
        self.points_xyz, self.points_rgb = points
        self.extra = extra or {}
        self.provenance = provenance or {}


def _read_internal(src: Path, cfg: IngestSettings) -> _Source:
    if not (src / SCENE_JSON).is_file():
        raise InputError(f"{src / SCENE_JSON} does not exist (layout 'internal'/'demo' needs scene.json + images/)")
    try:
        scene = read_scene(src)
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if str(src) in msg else f"{src / SCENE_JSON}: {msg}") from exc
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{src / SCENE_JSON}: malformed scene file ({exc!r})") from exc
    views = [SourceView(f.name, src / IMAGES_DIR / f.name, f.camera, scene.frame_size(i), f.c2w)
             for i, f in enumerate(scene.frames)]
    extra = {k: v for k, v in scene.extra.items() if k not in ("ingest", "frame_sizes")}
    return _Source(views, (scene.points_xyz, scene.points_rgb), extra,
                   {"source_layout": scene.layout})


def _read_folder(src: Path, cfg: IngestSettings) -> _Source:
    if not src.is_dir():
        raise InputError(f"image folder {src} is not a directory")
    folder = src
    if not list_images(src) and (src / IMAGES_DIR).is_dir():
        folder = src / IMAGES_DIR
    files = list_images(folder)
    if not files:
        raise InputError(f"no image files ({', '.join(IMAGE_EXTS)}) in {src}")
    views = [SourceView(p.name, p) for p in files]
    return _Source(views, extra={"intrinsics_guess": True},
                   provenance={"image_dir": str(folder)})


def _read_colmap(src: Path, cfg: IngestSettings, sequential: bool = False) -> _Source:
    model_dir = colmap_io.find_model_dir(src)
    if model_dir is None:
        if (src / "sparse").is_dir():
            subs = sorted((p for p in (src / "sparse").iterdir() if colmap_io.is_model_dir(p)),
                          key=lambda p: natural_key(p.name))
            if subs:
                model_dir = subs[0]
        if model_dir is None:
            raise InputError(f"no COLMAP sparse model (cameras/images/points3D .bin or .txt) in "
                             f"{src / 'sparse' / '0'} or {src / 'sparse'}")
    image_dir = src / IMAGES_DIR
    if not image_dir.is_dir():
        raise InputError(f"image folder {image_dir} does not exist")
    with timed(f"read COLMAP model {model_dir}", log):
        rec = colmap_io.load_reconstruction(model_dir)
    views = colmap_io.views_from_reconstruction(rec, image_dir, str(model_dir))
    if not views:
        raise InputError(f"COLMAP model {model_dir} has no registered images")
    for v in views:
        if not v.path.is_file():
            raise InputError(f"image {v.path} referenced by COLMAP model {model_dir} does not exist")
    in_model = {v.path.resolve() for v in views}
    unregistered = [p.name for p in list_images(image_dir) if p.resolve() not in in_model]
    if unregistered:
        log.warning("%d image(s) in %s are not in the COLMAP model and are skipped",
                    len(unregistered), image_dir)
    xyz, rgb = colmap_io.points_from_reconstruction(rec)
    extra = {"sequential": True} if sequential else {}
    return _Source(views, (xyz, rgb), extra,
                   {"model_dir": str(model_dir), "unregistered_images": unregistered})


def _read_mvimgnet(src: Path, cfg: IngestSettings) -> _Source:
    return _read_colmap(src, cfg, sequential=True)


_IMAGES_N = re.compile(r"^images(?:_(\d+))?$")


def _dl3dv_json(src: Path) -> Path:
    for cand in (src / "transforms.json", src / "nerfstudio" / "transforms.json"):
        if cand.is_file():
            return cand
    raise InputError(f"DL3DV scene {src} has no transforms.json (looked in {src} and {src / 'nerfstudio'})")


def _read_dl3dv(src: Path, cfg: IngestSettings) -> _Source:
    json_path = _dl3dv_json(src)
    root = json_path.parent
    data = nerf_io.load_transforms_json(json_path)
    # Image folders images/, images_2/, ... beside the json.
    folders = {}
    for p in root.iterdir():
        m = _IMAGES_N.match(p.name)
        if m and p.is_dir():
            folders[p.name] = int(m.group(1) or 1)
    sub = cfg.images_subdir
    if sub is not None:
        if not (root / sub).is_dir():
            raise ConfigError(f"ingest.images_subdir: folder {root / sub} does not exist")
        chosen = sub
    else:
        if not folders:
            raise InputError(f"DL3DV scene {root} has no images_N folder")
        by_res = sorted(folders, key=lambda k: folders[k])  # largest resolution first
        chosen = by_res[0]
        w0 = data.get("w")
        if cfg.max_side and w0 and data.get("h"):
            long_side = max(float(w0), float(data["h"]))
            fits = [k for k in by_res if long_side / folders[k] >= cfg.max_side]
            if fits:
                chosen = fits[-1]  # the smallest folder still at least max_side
    img_dir = root / chosen
    log.info("DL3DV: reading images from %s", img_dir)
    views = nerf_io.views_from_transforms(data, root, str(json_path), image_size=None
                                          if "w" in data else _first_size(img_dir))
    stems = {p.stem: p for p in img_dir.iterdir() if is_image_file(p)}
    for v in views:
        base = Path(v.name).name
        p = img_dir / base
        if not p.is_file() and Path(base).stem in stems:
            p = stems[Path(base).stem]
        v.path = p
        v.name = base
    views = sort_views(views)
    xyz = rgb = None
    prov: dict[str, Any] = {"transforms": str(json_path), "images_subdir": chosen}
    colmap_dir = None
    # colmap/ beside the json, or (DL3DV benchmark release) colmap/ or gaussian_splat/ in the scene
    for cand in (root / "colmap", src / "colmap", src / "gaussian_splat"):
        if colmap_dir is None and cand.is_dir():
            colmap_dir = colmap_io.find_model_dir(cand)
    if colmap_dir is not None:
        xyz, rgb, info = _aligned_points(colmap_dir, views)
        prov["colmap_points"] = info
    return _Source(views, (xyz, rgb), {"sequential": True}, prov)


def _first_size(folder: Path) -> tuple[int, int] | None:
    files = list_images(folder)
    if not files:
        return None
    img = decode_image(read_image_bytes(files[0]), str(files[0]))
    return img.shape[1], img.shape[0]


def _aligned_points(model_dir: Path, views: list[SourceView]):
    """COLMAP points mapped into the json world by a similarity fitted on camera
    centres of images present in both (matched by file stem)."""
    from gs2e.common.so3 import umeyama

    rec = colmap_io.load_reconstruction(model_dir)
    xyz, rgb = colmap_io.points_from_reconstruction(rec)
    if xyz is None:
        return None, None, {"model_dir": str(model_dir), "used": False, "reason": "no points"}
    cv = {Path(v.name).stem: v for v in colmap_io.views_from_reconstruction(rec)}
    src_c, dst_c = [], []
    for v in views:
        m = cv.get(Path(v.name).stem)
        if m is not None and v.c2w is not None:
            src_c.append(m.c2w[:3, 3])
            dst_c.append(v.c2w[:3, 3])
    info: dict[str, Any] = {"model_dir": str(model_dir), "matched_cameras": len(src_c)}
    if len(src_c) < 3:
        log.warning("DL3DV: only %d cameras shared with %s; its points are not used", len(src_c), model_dir)
        return None, None, {**info, "used": False}
    src_c, dst_c = np.asarray(src_c), np.asarray(dst_c)
    s, R, t = umeyama(src_c, dst_c)
    resid = np.linalg.norm(s * src_c @ R.T + t - dst_c, axis=1)
    extent = np.linalg.norm(dst_c - dst_c.mean(0), axis=1).max()
    rms = float(np.sqrt(np.mean(resid ** 2)))
    info.update(scale=float(s), rms_camera_error=rms, extent=float(extent))
    if not extent > 0 or rms > 0.01 * extent:
        log.warning("DL3DV: COLMAP cameras do not match transforms.json (rms %.3g vs extent %.3g); "
                    "its points are not used", rms, extent)
        return None, None, {**info, "used": False}
    return s * xyz @ R.T + t, rgb, {**info, "used": True}


def _nerf_json(src: Path) -> Path:
    if src.is_file():
        return src
    for name in ("transforms.json", "transforms_train.json"):
        if (src / name).is_file():
            return src / name
    raise InputError(f"no transforms.json or transforms_train.json in {src}")


def _read_nerf(src: Path, cfg: IngestSettings) -> _Source:
    json_path = _nerf_json(src)
    data = nerf_io.load_transforms_json(json_path)
    views = nerf_io.views_from_transforms(data, json_path.parent, str(json_path))
    prov = {"transforms": str(json_path)}
    if "applied_transform" in data:
        prov["applied_transform_undone"] = True
    return _Source(sort_views(views), provenance=prov)


def _read_ecd(src: Path, cfg: IngestSettings) -> _Source:
    from gs2e.io.ecd import read_ecd_views

    views, prov = read_ecd_views(src)
    return _Source(views, extra={"sequential": True}, provenance=prov)


def _read_llff(src: Path, cfg: IngestSettings) -> _Source:
    from gs2e.io.llff import read_llff_views

    views, prov = read_llff_views(src)
    return _Source(views, provenance=prov)


def _read_projection(src: Path, cfg: IngestSettings) -> _Source:
    from gs2e.io.llff import read_projection_views

    views, prov = read_projection_views(src)
    return _Source(views, provenance=prov)


_READERS = {
    "demo": _read_internal,
    "internal": _read_internal,
    "folder": _read_folder,
    "colmap": _read_colmap,
    "mvimgnet": _read_mvimgnet,
    "dl3dv": _read_dl3dv,
    "nerf": _read_nerf,
    "ecd": _read_ecd,
    "llff": _read_llff,
    "projection": _read_projection,
}


# ---------------------------------------------------------------- the stage

def _upright(img: np.ndarray, view: SourceView, exif: dict[str, list[str]]) -> np.ndarray:
    """The view's image as it is meant to be seen (its EXIF orientation
    applied, the same in every layout), unless a camera came with it for the
    stored pixel grid (poses made by a tool that ignored EXIF, as COLMAP did
    before 2026): that view is kept as stored. ``exif`` collects the names."""
    o = exif_orientation(view.path)
    if o == 1:
        return img
    stored = (img.shape[1], img.shape[0])
    up = upright_size(stored, o)
    if view.camera is not None and view.size is not None:
        declared = tuple(view.size)
        ratio = lambda s: s[0] / s[1]  # noqa: E731
        if up == stored:  # a flip or half turn, or a square view: the size cannot tell
            exif["ambiguous"].append(view.name)
            return img
        if abs(ratio(declared) - ratio(stored)) <= abs(ratio(declared) - ratio(up)):
            exif["kept_stored"].append(view.name)
            return img
    exif["applied"].append(view.name)
    return apply_orientation(img, o)


def _declared_to_actual(view: SourceView, actual: tuple[int, int]) -> tuple[Camera | None, tuple[float, float]]:
    """Scale the view's camera from its declared size to the image's actual size."""
    if view.camera is None or view.size is None or tuple(view.size) == tuple(actual):
        return view.camera, (1.0, 1.0)
    sx, sy = actual[0] / view.size[0], actual[1] / view.size[1]
    if abs(sx - sy) > ASPECT_TOL * max(sx, sy):
        raise InputError(
            f"image {view.path} is {actual[0]}x{actual[1]} but its camera is for "
            f"{view.size[0]}x{view.size[1]} (different aspect ratio)")
    return view.camera.scaled(sx, sy), (sx, sy)


def _check_paths(src, layout: str, out_dir) -> tuple[Path, Path]:
    """(src, out_dir) as paths; ConfigError for an unknown layout, InputError
    for a missing source or an output folder that is it or inside it."""
    if layout not in LAYOUTS:
        raise ConfigError(f"layout '{layout}' is not one of {', '.join(LAYOUTS)}")
    src, out_dir = Path(src), Path(out_dir)
    if not src.exists():
        raise InputError(f"source {src} does not exist")
    if out_dir.resolve() == src.resolve() or src.resolve() in out_dir.resolve().parents:
        raise InputError(f"output folder {out_dir} must not be the source {src} or inside it")
    return src, out_dir


def _check_files(views: list[SourceView], src: Path) -> None:
    """Before decoding anything: at least 2 views, and every file there and
    not absurdly large (InputError naming the file)."""
    if len(views) < 2:
        raise InputError(f"scene {src} has {len(views)} usable view(s); at least 2 are needed")
    for v in views:
        if not v.path.is_file():
            raise InputError(f"image file {v.path} does not exist")
        check_image_size(v.path)


def _check_distinct(img: np.ndarray, i: int, views: list[SourceView], seen: dict[bytes, int]) -> None:
    """InputError naming both files when view ``i``'s decoded pixels equal an
    earlier view's (``seen``: pixel digest -> view index, updated)."""
    digest = hashlib.sha256(np.asarray(img.shape).tobytes() + img.tobytes()).digest()
    if digest in seen:
        raise InputError(f"duplicate views: images {views[seen[digest]].path} and {views[i].path} are identical")
    seen[digest] = i


def _log_exif(exif: dict[str, list[str]]) -> None:
    """Say what EXIF orientation did to the views (view names by outcome)."""
    if exif["applied"]:
        log.info("%d view(s) turned upright by their EXIF orientation (e.g. %s)", len(exif["applied"]),
                 exif["applied"][0])
    if exif["kept_stored"]:
        log.warning("%d view(s) have an EXIF orientation but cameras for the stored pixel grid "
                    "(e.g. %s): kept as stored, as their poses were made", len(exif["kept_stored"]),
                    exif["kept_stored"][0])
    if exif["ambiguous"]:
        log.warning("%d view(s) have an EXIF orientation that keeps their size (a flip, a half turn "
                    "or a square view) and given cameras (e.g. %s): which grid the poses were made "
                    "on cannot be told; kept as stored",
                    len(exif["ambiguous"]), exif["ambiguous"][0])


def ingest_scene(src: str | os.PathLike, layout: str, out_dir: str | os.PathLike,
                 cfg: IngestSettings | None = None) -> Scene:
    """Read the scene at ``src`` in ``layout`` and write the internal layout to ``out_dir``.

    Each view keeps its own size and orientation (a phone capture's portrait
    views stay portrait, with their own intrinsics), only downscaled by
    ``downscale`` and ``max_side``. The scene's width/height are the most common
    view size (the camera of its virtual trajectories, see
    :func:`gs2e.io.scene.main_size`); ``extra["frame_sizes"]`` lists each view's
    size when they differ. Views whose size is neither the first view's nor its
    rotation need ``allow_mixed_resolutions``.

    Parameters
    ----------
    src : source folder (or, for ``nerf``, a transforms json file).
    layout : one of ``LAYOUTS``.
    out_dir : output folder; written atomically (replaced only on success).
    cfg : the ``ingest`` settings (None: the schema's defaults).
        ``max_side: auto`` caps the longer side at ``SFM_MAX_SIDE`` px, a size
        that suits feature matching whatever the event sensor (training shrinks
        the views to what the sensor needs: ``splat.max_side``).

    Returns
    -------
    The written Scene (frame names are the PNG names under ``out_dir/images``).

    Raises
    ------
    InputError naming the file for missing/corrupt images, duplicate views,
    mixed resolutions, invalid poses, fewer than 2 views; ConfigError for bad cfg.
    """
    cfg = IngestSettings.defaults() if cfg is None else require(cfg, IngestSettings, "ingest_scene")
    if cfg.max_side == "auto":
        cfg = dataclasses.replace(cfg, max_side=SFM_MAX_SIDE)
    src, out_dir = _check_paths(src, layout, out_dir)

    with timed(f"scan {layout} scene {src}", log):
        source = _READERS[layout](src, cfg)
    views = source.views
    n_src = len(views)
    idx = subsample_indices(n_src, cfg.max_views)
    views = [views[i] for i in idx]
    log.info("%d views in the source, %d selected", n_src, len(views))
    _check_files(views, src)
    out_names = unique_png_names([v.name for v in views])

    frames: list[Frame] = []
    seen: dict[bytes, int] = {}
    src_sizes, out_sizes, scales, cam_scales = [], [], [], []
    exif = {"applied": [], "kept_stored": [], "ambiguous": []}  # view names by what EXIF did
    with timed(f"ingest {len(views)} images -> {out_dir}", log), atomic_dir(out_dir) as tmp:
        (tmp / IMAGES_DIR).mkdir()
        for i, v in enumerate(progress(views, desc="ingest images")):
            img = _upright(decode_image(read_image_bytes(v.path), str(v.path)), v, exif)
            h, w = img.shape[:2]
            _check_distinct(img, i, views, seen)
            if src_sizes and sorted((w, h)) != sorted(src_sizes[0]) and not cfg.allow_mixed_resolutions:
                raise InputError(
                    f"mixed resolutions: image {v.path} is {w}x{h} but {views[0].path} is "
                    f"{src_sizes[0][0]}x{src_sizes[0][1]} "
                    "(set ingest.allow_mixed_resolutions to keep each view at its own size)")
            src_sizes.append([w, h])
            cam, s0 = _declared_to_actual(v, (w, h))
            if cam is None:
                cam = guess_camera(w, h)
            img, cam, s1 = resize_with_camera(img, cam, scaled_size(w, h, cfg.downscale, cfg.max_side))
            out_sizes.append((img.shape[1], img.shape[0]))
            scales.append(list(s1))
            cam_scales.append([s0[0] * s1[0], s0[1] * s1[1]])
            write_png(tmp / IMAGES_DIR / out_names[i], img)
            frames.append(Frame(out_names[i], cam, v.c2w))
        out_size = main_size(out_sizes)
        extra = dict(source.extra)
        extra["ingest"] = {
            "layout": layout,
            "source": str(src),
            **source.provenance,
            "n_source_views": n_src,
            "subsample_indices": idx.tolist(),
            "original_names": [v.name for v in views],
            "source_sizes": src_sizes,
            "scale_xy": scales,
            "camera_scale_xy": cam_scales,
            "output_size": list(out_size),
            "main_size_views": sum(tuple(o) == tuple(out_size) for o in out_sizes),
            "config": cfg.as_dict(),
            # (only where EXIF turned or kept a view: other scenes' files keep their bytes)
            **({"exif_orientation": {k: v for k, v in exif.items() if v}} if any(exif.values()) else {}),
        }
        scene = Scene(out_size[0], out_size[1], frames, layout, str(src),
                      source.points_xyz, source.points_rgb, with_frame_sizes(extra, out_sizes, out_size))
        write_scene_json(scene, tmp)
    _log_exif(exif)
    log.info("wrote %d views (%dx%d, poses: %s, points: %s) to %s", len(frames), out_size[0],
             out_size[1], scene.has_poses, 0 if scene.points_xyz is None else len(scene.points_xyz), out_dir)
    return scene
