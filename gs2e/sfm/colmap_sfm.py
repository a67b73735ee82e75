"""COLMAP structure-from-motion through pycolmap.

Steps: SIFT extraction (COLMAP's, or OpenCV's: gs2e.sfm.features) -> matching
(exhaustive or sequential pairs; descriptors matched by COLMAP's index or by
gs2e's GEMMs, gs2e.sfm.matching; verified by COLMAP) -> incremental mapping (or, when the scene has poses
and ``reuse_poses`` is set, triangulation with the given poses) -> undistortion
to PINHOLE (COLMAP's cameras, views resampled by OpenCV: gs2e.sfm.undistort). The output folder is an
internal-layout scene (undistorted ``images/``, ``scene.json``,
``points3d.npz``) plus ``sparse/0`` (COLMAP binary model), the input layout
3DGS implementations expect.
"""

from __future__ import annotations

import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gs2e.common.atomic import atomic_dir, scratch_dir, write_json_atomic
from gs2e.common.errors import InputError
from gs2e.common.log import get_logger, timed
from gs2e.common.settings import require
from gs2e.common.threads import pick_threads, set_threads
from gs2e.metrics.table import write_metrics
from gs2e.io.scene import IMAGES_DIR, Scene, read_scene, write_scene_json
from gs2e.sfm.align import alignment_errors
from gs2e.sfm.settings import SfmSettings

log = get_logger("gs2e.sfm")


def choose_matcher(cfg: SfmSettings, n_views: int) -> str:
    """'exhaustive' or 'sequential' for ``cfg.matcher`` (auto: by view count)."""
    if cfg.matcher != "auto":
        return cfg.matcher
    return "exhaustive" if n_views <= cfg.exhaustive_max_views else "sequential"


def _device(cfg: SfmSettings):
    import pycolmap

    return pycolmap.Device.cuda if cfg.gpu else pycolmap.Device.cpu


def sift_max_side_px(cfg: SfmSettings, scene: Scene) -> int:
    """The longest side (px) SIFT sees of any of the scene's photos
    (gs2e.sfm.features.sift_side_px for ``sfm.max_image_size``)."""
    from gs2e.sfm.features import sift_side_px

    return max(sift_side_px(cfg.max_image_size, scene.frame_size(i))
               for i in range(len(scene.frames)))


def _import_images(db: Path, image_dir: Path, names: list[str], camera_mode, camera_model: str) -> None:
    """Images and cameras into a new database, one by one in name order: the
    extractor's threads would otherwise number them in the order they finish,
    and the mapper's result depends on the image ids."""
    import pycolmap

    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = camera_model
    pycolmap.Database.open(str(db)).close()  # creates the (empty) database
    pycolmap.import_images(db, image_dir, camera_mode=camera_mode, image_names=names, options=reader)


def _one_camera_per_size(db: Path) -> None:
    """Every view of the database on the camera of the first view of its size
    (and that camera's rig); the other cameras and rigs are removed.

    Run after the pairs are verified with a camera per view: COLMAP verifies
    a pair of one camera without a focal prior by its shared-focal solver,
    about 7x the CPU of its uncalibrated path (8.6 against 1.2 s on a 50-view
    1080p capture; the whole SfM of temple_ring 0.77x the CPU, the same views
    and points), while the mapper gains from the shared intrinsics."""
    import sqlite3

    import pycolmap

    database = pycolmap.Database.open(str(db))
    try:
        cams = {c.camera_id: c for c in database.read_all_cameras()}
        rigs = {r.ref_sensor_id.id: r for r in database.read_all_rigs()}
        images = sorted(database.read_all_images(), key=lambda im: im.image_id)
        frames = sorted(database.read_all_frames(), key=lambda f: f.frame_id)
        size = {cid: (c.model.name, c.width, c.height) for cid, c in cams.items()}
        first: dict[tuple, int] = {}
        for im in images:
            first.setdefault(size[im.camera_id], im.camera_id)
        target = {im.image_id: first[size[im.camera_id]] for im in images}
        database.clear_frames()
        database.clear_rigs()
        for cid in sorted(set(first.values())):
            database.write_rig(rigs[cid], use_rig_id=True)
        for f in frames:  # a view per frame, as COLMAP's image reader leaves them
            (iid,) = [int(d.id) for d in f.image_ids]
            frame = pycolmap.Frame(frame_id=f.frame_id, rig_id=rigs[target[iid]].rig_id)
            frame.add_data_id(pycolmap.data_t(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, target[iid]), iid))
            database.write_frame(frame, use_frame_id=True)
        for im in images:
            im.camera_id = target[im.image_id]
            database.update_image(im)
    finally:
        database.close()
    with sqlite3.connect(db) as con:  # pycolmap deletes no single camera
        con.execute("DELETE FROM cameras WHERE camera_id NOT IN (SELECT camera_id FROM images)")
    con.close()


def _extract(db: Path, image_dir: Path, names: list[str], cfg: SfmSettings, threads: int,
             camera_mode, camera_model: str) -> None:
    """SIFT keypoints and descriptors of every view into the database, each
    view decoded and shrunk by gs2e (gs2e.sfm.features): COLMAP's SIFT
    (``sfm.extractor: colmap``; on the GPU with ``sfm.gpu``) or OpenCV's
    (``opencv``). ``threads`` views at a time, OpenCV on one thread per view
    (its own threads would make the keypoint order depend on timing); each
    view's features depend on that view alone, so the bytes do not depend on
    the thread count (COLMAP's SIFT holds the GIL: its views run one at a
    time while the next ones are decoded)."""
    from concurrent.futures import ThreadPoolExecutor

    import cv2
    import pycolmap

    from gs2e.common.progress import progress
    from gs2e.sfm.features import colmap_sift_features, sift_features

    _import_images(db, image_dir, names, camera_mode, camera_model)
    size, n_max = cfg.max_image_size, int(cfg.max_num_features)
    use_colmap = cfg.extractor == "colmap" or cfg.gpu
    device = _device(cfg)

    def one(name: str):
        path = image_dir / name
        gray = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE | cv2.IMREAD_IGNORE_ORIENTATION)
        if gray is None:
            raise InputError(f"{path}: cannot read the image for SIFT")
        if use_colmap:
            return colmap_sift_features(gray, size, n_max, cfg.sift_first_octave, device)
        return sift_features(gray, size, n_max)

    database = pycolmap.Database.open(str(db))
    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        images = sorted(database.read_all_images(), key=lambda im: im.image_id)
        with ThreadPoolExecutor(max(1, threads)) as pool:
            for im, (keypoints, descriptors) in zip(
                    images, progress(pool.map(lambda im: one(im.name), images), total=len(images),
                                     desc="SIFT", unit="view")):
                database.write_keypoints(im.image_id, keypoints)
                database.write_descriptors(im.image_id, pycolmap.FeatureDescriptors(
                    pycolmap.FeatureExtractorType.SIFT, descriptors))
    finally:
        cv2.setNumThreads(cv_threads)
        database.close()


def _verification_options(seed: int):
    import pycolmap

    # Geometric verification's RANSAC draws from a time-seeded PRNG unless
    # given a seed: unseeded, two runs keep different inlier matches.
    vopts = pycolmap.TwoViewGeometryOptions()
    vopts.ransac.random_seed = int(seed)
    return vopts


def _pairing_options(cfg: SfmSettings, threads: int):
    import pycolmap

    popts = pycolmap.SequentialPairingOptions()
    popts.overlap = int(cfg.sequential_overlap)
    popts.loop_detection = bool(cfg.sequential_loop_detection)
    popts.num_threads = threads
    return popts


def _match_colmap(db: Path, matcher: str, cfg: SfmSettings, threads: int, seed: int) -> None:
    """COLMAP's own matching and verification (its faiss index on the CPU, SiftGPU with ``sfm.gpu``)."""
    import pycolmap

    mopts = pycolmap.FeatureMatchingOptions()
    mopts.num_threads = threads
    mopts.use_gpu = bool(cfg.gpu)
    vopts = _verification_options(seed)
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(db, matching_options=mopts, verification_options=vopts, device=_device(cfg))
    else:
        pycolmap.match_sequential(db, matching_options=mopts, pairing_options=_pairing_options(cfg, threads),
                                  verification_options=vopts, device=_device(cfg))


def unique_pairs(pairs) -> list[tuple[int, int]]:
    """Image-id pairs as COLMAP's matcher takes them: each pair once in the
    orientation it first comes in (the stored matches' order follows it), no
    view with itself (loop detection repeats pairs; the database takes a pair
    once)."""
    first: dict[tuple[int, int], tuple[int, int]] = {}
    for a, b in pairs:
        if a != b:
            first.setdefault((min(a, b), max(a, b)), (int(a), int(b)))
    return list(first.values())


def _match_gemm(db: Path, matcher: str, cfg: SfmSettings, threads: int, colmap_threads: int, seed: int,
                timings: dict[str, float]) -> None:
    """The view pairs COLMAP's pairing chooses, matched by gs2e (COLMAP's
    brute-force rule as GEMMs, gs2e.sfm.matching: ``threads`` views at a
    time, the same matches on any thread count) and verified by COLMAP's
    own matcher, which does not match again pairs that have matches but
    verifies them."""
    import pycolmap

    from gs2e.sfm.matching import match_views

    vopts = _verification_options(seed)
    database = pycolmap.Database.open(str(db))
    try:
        with timed("descriptor_matching", log, timings):
            generator = (pycolmap.ExhaustivePairGenerator(pycolmap.ExhaustivePairingOptions(), database)
                         if matcher == "exhaustive" else
                         pycolmap.SequentialPairGenerator(_pairing_options(cfg, colmap_threads), database))
            pairs = unique_pairs(generator.all_pairs())
            ids = sorted({i for pair in pairs for i in pair})
            view = {image_id: v for v, image_id in enumerate(ids)}
            sift = pycolmap.SiftMatchingOptions()
            matches = match_views([np.asarray(database.read_descriptors(i).data, np.uint8) for i in ids],
                                  np.array([(view[a], view[b]) for a, b in pairs], np.int64).reshape(-1, 2),
                                  sift.max_ratio, sift.max_distance, sift.cross_check, threads)
            for (a, b), m in zip(pairs, matches):
                # stored as COLMAP's matcher stores them: fewer than verification needs as none
                database.write_matches(a, b, m if len(m) >= vopts.min_num_inliers else m[:0])
    finally:
        database.close()
    with timed("verification", log, timings):
        # COLMAP's matcher on pairs that have matches only verifies them: the
        # database ends as its brute-force matcher leaves it, byte for byte
        _match_colmap(db, matcher, cfg, colmap_threads, seed)


# sfm.bundle_adjustment: fast = the schedule of COLMAP's automatic reconstructor
# at its low quality level (COLMAP 3.x's 25 / 50 iterations halved, a global
# adjustment each time the model grows by 32 % instead of 10 %, at most 2
# refinement rounds): 0.6x the mapping CPU on mouse_colmap, same views
# registered (benchmarks/bench_sfm_size.py).
FAST_BUNDLE_ADJUSTMENT = {"ba_local_max_num_iterations": 12, "ba_global_max_num_iterations": 25,
                          "ba_global_frames_ratio": 1.32, "ba_global_points_ratio": 1.32,
                          "ba_global_max_refinements": 2}


def _mapper_options(cfg: SfmSettings, threads: int, seed: int):
    import pycolmap

    opts = pycolmap.IncrementalPipelineOptions()
    opts.num_threads = threads
    opts.random_seed = int(seed)
    opts.extract_colors = False  # taken while undistorting (_undistort): one decode per photo
    if cfg.bundle_adjustment == "fast":
        for key, value in FAST_BUNDLE_ADJUSTMENT.items():
            setattr(opts, key, value)
    return opts


def _known_pose_reconstruction(db_path: Path, scene: Scene):
    """A reconstruction with the scene's cameras and poses whose image and camera
    ids are those of the feature database (required by triangulate_points)."""
    import pycolmap

    from gs2e.io.colmap import reconstruction_from_scene

    known = reconstruction_from_scene(scene)
    db = pycolmap.Database.open(str(db_path))
    try:
        db_images = db.read_all_images()
    finally:
        db.close()
    rec = pycolmap.Reconstruction()
    for im in sorted(db_images, key=lambda i: i.image_id):
        src = known.find_image_with_name(im.name)
        if src is None:
            raise InputError(f"image {im.name} of the database is not in the scene")
        cam = pycolmap.Camera(known.cameras[src.camera_id].todict())
        cam.camera_id = im.camera_id
        if not rec.exists_camera(im.camera_id):
            rec.add_camera_with_trivial_rig(cam)
        new = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=im.image_id)
        rec.add_image_with_trivial_frame(new, src.cam_from_world())
    return rec


@dataclass
class _Run:
    """What the steps of one SfM run share."""

    scene: Scene
    scene_dir: Path
    cfg: SfmSettings
    seed: int
    threads: int  # extraction, undistortion
    colmap_threads: int  # COLMAP's matching and mapping
    work: Path  # scratch folder: database, models
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def image_dir(self) -> Path:
        return self.scene_dir / IMAGES_DIR

    @property
    def names(self) -> list[str]:
        return [f.name for f in self.scene.frames]

    @property
    def db(self) -> Path:
        return self.work / "database.db"

    @property
    def model_dir(self) -> Path:
        return self.work / "model"

    def features(self, camera_mode, camera_model: str, matcher: str) -> None:
        """SIFT features and verified matches into the run's database."""
        with timed("extraction", log, self.timings):
            _extract(self.db, self.image_dir, self.names, self.cfg, self.threads, camera_mode, camera_model)
        with timed("matching", log, self.timings):
            if self.cfg.gpu or self.cfg.descriptor_matcher == "colmap":
                _match_colmap(self.db, matcher, self.cfg, self.colmap_threads, self.seed)
            else:
                _match_gemm(self.db, matcher, self.cfg, self.threads, self.colmap_threads, self.seed, self.timings)


def _reconstruct_given(run: _Run):
    """The scene's own cameras, poses and points (COLMAP project, demo, DL3DV
    colmap/): nothing to recover."""
    from gs2e.io.colmap import reconstruction_from_scene

    rec = reconstruction_from_scene(run.scene)
    rec.write(run.model_dir)
    return rec


def _reconstruct_known_poses(run: _Run, matcher: str):
    """The scene's own cameras and poses; points triangulated from matches."""
    import pycolmap

    frames = run.scene.frames
    same_k = len({(f.camera.model, f.camera.fx, f.camera.fy, f.camera.cx, f.camera.cy, *f.camera.dist)
                  for f in frames}) == 1
    mode = pycolmap.CameraMode.SINGLE if same_k else pycolmap.CameraMode.PER_IMAGE
    run.features(mode, frames[0].camera.model, matcher)
    with timed("mapping", log, run.timings):
        rec = _known_pose_reconstruction(run.db, run.scene)
        return pycolmap.triangulate_points(rec, run.db, run.image_dir, run.model_dir,
                                           options=_mapper_options(run.cfg, run.colmap_threads, run.seed))


def _reconstruct_incremental(run: _Run, matcher: str):
    """Cameras, poses and points recovered by COLMAP's incremental mapper (its
    largest model)."""
    import pycolmap

    cfg = run.cfg
    # A camera per view while the pairs are verified, then (sfm.single_camera)
    # one camera per view size: a phone's portrait and landscape views share a
    # lens but not a pixel grid. (COLMAP's AUTO mode gives each view of a PNG
    # capture its own camera: no EXIF to group by.)
    run.features(pycolmap.CameraMode.PER_IMAGE, cfg.camera_model, matcher)
    if cfg.single_camera:
        _one_camera_per_size(run.db)
    with timed("mapping", log, run.timings):
        recs = pycolmap.incremental_mapping(run.db, run.image_dir, run.work / "sparse",
                                            options=_mapper_options(run.cfg, run.colmap_threads, run.seed))
    if not recs:
        raise InputError(f"{run.scene_dir}: COLMAP registered no views (no initial pair found)")
    rec = max(recs.values(), key=lambda r: r.num_reg_images())
    rec.write(run.model_dir)
    return rec


def _check_registration(rec, run: _Run) -> set[str]:
    """Names of the registered views; InputError naming the others when too few register."""
    names = run.names
    n_reg, n_views = rec.num_reg_images(), len(names)
    registered = {rec.image(i).name for i in rec.reg_image_ids()}
    rate = n_reg / n_views
    if rate < run.cfg.min_registered_fraction:
        missing = [n for n in names if n not in registered]
        raise InputError(
            f"{run.scene_dir}: only {n_reg} of {n_views} views registered "
            f"({rate:.0%} < sfm.min_registered_fraction={run.cfg.min_registered_fraction}); "
            f"not registered: {', '.join(missing[:10])}{' ...' if len(missing) > 10 else ''}")
    return registered


def _undistort(model_dir: Path, image_dir: Path, undist: Path, threads: int) -> None:
    """COLMAP's undistorted model (PINHOLE cameras, 2D points moved with them)
    and the registered views resampled to it, into ``undist`` (``sparse/``,
    ``images/``), with the 3D points' colours. The views are resampled with
    OpenCV (gs2e.sfm.undistort), ``threads`` at a time, and the colours are
    taken from the photos decoded for that (the mapper leaves them black: it
    would decode every photo once more); a camera model OpenCV cannot express
    leaves all of it to COLMAP (as do views that are not PNG files, which
    ingest never writes)."""
    from concurrent.futures import ThreadPoolExecutor

    import cv2
    import pycolmap

    from gs2e.io.images import read_image, write_png
    from gs2e.sfm.undistort import OPENCV_DISTORTION, bilinear_colors, undistort_image, undistortion_maps

    rec = pycolmap.Reconstruction(str(model_dir))
    images = [rec.image(i) for i in sorted(rec.reg_image_ids())]
    if not images or any(rec.cameras[im.camera_id].model.name not in OPENCV_DISTORTION
                         or Path(im.name).suffix.lower() != ".png" for im in images):
        rec.extract_colors_for_all_images(str(image_dir))
        rec.write(model_dir)
        pycolmap.undistort_images(undist, model_dir, image_dir, num_threads=threads)
        return
    # Undistorting one view writes the whole undistorted model; that view is rewritten below.
    pycolmap.undistort_images(undist, model_dir, image_dir, image_names=[images[0].name], num_threads=1)
    undistorted = pycolmap.Reconstruction(str(undist / "sparse"))
    maps = {}
    for im in images:
        if im.camera_id not in maps:
            src, dst = rec.cameras[im.camera_id], undistorted.cameras[im.camera_id]
            maps[im.camera_id] = undistortion_maps(src.model.name, src.params, dst.params, (dst.width, dst.height))
    observations = {}
    for im in images:
        seen = [p for p in im.points2D if p.has_point3D()]
        observations[im.image_id] = (np.array([p.xy for p in seen], np.float64).reshape(-1, 2),
                                     np.array([p.point3D_id for p in seen], np.int64))

    def one(im):
        rgb = read_image(image_dir / im.name)
        write_png(undist / "images" / im.name, undistort_image(rgb, maps[im.camera_id]))
        xy, ids = observations[im.image_id]
        colors, valid = bilinear_colors(rgb, xy)
        return ids[valid], colors[valid]

    cv_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with ThreadPoolExecutor(max(1, threads)) as pool:
            seen = list(pool.map(one, images))
    finally:
        cv2.setNumThreads(cv_threads)
    # COLMAP's colour of a point: the mean over the views that see it, rounded
    ids = np.concatenate([s[0] for s in seen])
    uniq, inverse = np.unique(ids, return_inverse=True)
    sums = np.zeros((len(uniq), 3))
    np.add.at(sums, inverse, np.concatenate([s[1] for s in seen]))
    means = np.round(sums / np.bincount(inverse, minlength=len(uniq))[:, None]).astype(np.uint8)
    for pid, color in zip(uniq.tolist(), means):
        undistorted.points3D[pid].color = color
    undistorted.write(undist / "sparse")


def _write_undistorted(run: _Run, out: Path, threads: int, keep_points: bool, registered: set[str]) -> Scene:
    """Undistort the model's views to PINHOLE and write them as an internal-layout
    scene plus ``sparse/0`` into ``out``; returns that scene."""
    import pycolmap

    from gs2e.io.colmap import scene_from_reconstruction

    undist = run.work / "undist"
    with timed("undistortion", log, run.timings):
        _undistort(run.model_dir, run.image_dir, undist, threads)
    with timed("writing", log, run.timings):
        scene = run.scene
        out_scene = scene_from_reconstruction(pycolmap.Reconstruction(str(undist / "sparse")))
        if keep_points:
            out_scene.points_xyz, out_scene.points_rgb = scene.points_xyz, scene.points_rgb
        out_scene.layout = "sfm"
        out_scene.source = str(run.scene_dir)
        # (frame_sizes: views of other sizes or orientations keep theirs)
        out_scene.extra = {**out_scene.extra, "input_extra": scene.extra, "registered": sorted(registered)}
        shutil.move(str(undist / "images"), str(out / IMAGES_DIR))
        (out / "sparse").mkdir()
        shutil.move(str(undist / "sparse"), str(out / "sparse" / "0"))
        write_scene_json(out_scene, out)
    return out_scene


def _camera_errors(scene: Scene, out_scene: Scene) -> dict[str, float]:
    """Errors of the recovered cameras against the input poses (after a
    similarity alignment; at least 3 common views), ``gt_``-prefixed."""
    gt = {f.name: f.c2w for f in scene.frames}
    common = [f for f in out_scene.frames if f.name in gt]
    if len(common) < 3:
        return {}
    errs = alignment_errors(np.stack([f.c2w for f in common]), np.stack([gt[f.name] for f in common]))
    return {f"gt_{k}": v for k, v in errs.items()}


def run_sfm(scene_dir: str | Path, out_dir: str | Path, cfg: SfmSettings, seed: int = 0,
            threads: int | None = None, scene_id: str | None = None) -> dict[str, Any]:
    """Recover cameras and sparse points for the scene in ``scene_dir``.

    Two modes: with ``cfg.reuse_poses`` and a scene that has poses, the
    known cameras are kept (``given`` when the scene has points too, else
    ``triangulate``); otherwise COLMAP's ``incremental`` mapping recovers them.

    Parameters
    ----------
    scene_dir : internal-layout scene (output of ``gs2e ingest``).
    out_dir : output folder, written atomically (nothing is left on failure).
    cfg : the ``sfm`` settings.
    seed : seed of COLMAP's RANSAC/mapper.
    threads : CPU threads (None: ``cfg.num_threads``; -1: the CPUs this
        process may use, see gs2e.common.threads).

    Returns
    -------
    dict of statistics (also written to ``out_dir/sfm_stats.json``): views,
    registered views and rate, points, mean reprojection error (px), mean track
    length, matcher, mode, per-step times (s), and camera errors against the
    input poses when the input had poses and mapping was run. The same values
    are written as a one-row table ``out_dir/metrics.parquet``.

    Raises
    ------
    InputError if fewer than ``cfg.min_registered_fraction`` of the views
    register (the message names the scene folder and unregistered views).
    """
    scene_dir, out_dir = Path(scene_dir), Path(out_dir)
    scene = read_scene(scene_dir)
    n_views = len(scene.frames)
    if n_views < 2:
        raise InputError(f"{scene_dir}: SfM needs at least 2 views, got {n_views}")
    cfg = require(cfg, SfmSettings, "run_sfm")
    threads = set_threads(pick_threads(threads, cfg.num_threads))
    # COLMAP's multi-threaded extraction, matching and mapping depend on thread
    # timing (which job finishes first), so runs differ under load; one thread
    # gives the same bytes on every machine (undistortion stays parallel).
    colmap_threads = 1 if cfg.deterministic else threads
    reuse = bool(cfg.reuse_poses) and scene.has_poses
    matcher = choose_matcher(cfg, n_views)
    keep_points = reuse and scene.points_xyz is not None and len(scene.points_xyz) > 0
    mode = "given" if keep_points else "triangulate" if reuse else "incremental"
    t_start = time.perf_counter()
    log.info("SfM on %s: %d views, matcher=%s, mode=%s, threads=%d (COLMAP %d)", scene_dir, n_views,
             "none" if mode == "given" else matcher, mode, threads, colmap_threads)

    with atomic_dir(out_dir) as out, scratch_dir(out_dir) as work:
        run = _Run(scene, scene_dir, cfg, seed, threads, colmap_threads, work)
        run.model_dir.mkdir()
        if mode == "given":
            rec, matcher = _reconstruct_given(run), "none"
        elif mode == "triangulate":
            rec = _reconstruct_known_poses(run, matcher)
        else:
            rec = _reconstruct_incremental(run, matcher)
        registered = _check_registration(rec, run)
        out_scene = _write_undistorted(run, out, threads, keep_points, registered)
        n_reg = rec.num_reg_images()
        stats: dict[str, Any] = {
            "n_views": n_views,
            "n_registered": n_reg,
            "registration_rate": n_reg / n_views,
            "n_points": int(len(scene.points_xyz)) if keep_points else int(rec.num_points3D()),
            "mean_reproj_error_px": (float(rec.compute_mean_reprojection_error())
                                     if rec.num_points3D() and not keep_points else float("nan")),
            "mean_track_length": float(rec.compute_mean_track_length()) if rec.num_points3D() else float("nan"),
            "matcher": matcher,
            "sift_max_image_size": None if mode == "given" else sift_max_side_px(cfg, scene),
            "sift_extractor": None if mode == "given" else "colmap" if cfg.gpu else cfg.extractor,
            "bundle_adjustment": cfg.bundle_adjustment if mode == "incremental" else None,
            "mode": mode,
            "threads": threads,
            **{f"time_{k}_s": v for k, v in run.timings.items()},
        }
        if scene.has_poses and mode == "incremental":
            stats.update(_camera_errors(scene, out_scene))
        stats["time_total_s"] = time.perf_counter() - t_start
        write_json_atomic(out / "sfm_stats.json", {k: (None if isinstance(v, float) and not np.isfinite(v) else v)
                                                   for k, v in stats.items()})
        write_metrics(out / "metrics.parquet", stats, scene_id=scene_id or scene_dir.parent.name,
                      stage="sfm")
    log.info("SfM: %d/%d views registered, %d points, %s px mean reprojection error, %.1f s",
             n_reg, n_views, stats["n_points"], f"{stats['mean_reproj_error_px']:.3f}", stats["time_total_s"])
    return stats
