"""Descriptor matching as GEMMs (gs2e.sfm.matching): COLMAP's brute-force rule,
checked against a direct transcription of it on tie-heavy descriptors and
against COLMAP's own brute-force matcher on real features."""

from __future__ import annotations

import ctypes
import ctypes.util
import shutil

import numpy as np
import pytest

from gs2e.sfm.matching import SQ_DESCRIPTOR_NORM, angle_table, best_two, match_views
from tests.conftest import shared_data

_LIBM = ctypes.CDLL(ctypes.util.find_library("m"))
_LIBM.acosf.restype, _LIBM.acosf.argtypes = ctypes.c_float, [ctypes.c_float]


def _acosf(x: np.float32) -> np.float32:
    """libm's float acos, what COLMAP's std::acos of a float calls."""
    return np.float32(_LIBM.acosf(float(x)))


def _one_way_reference(dots: np.ndarray, max_ratio: float, max_distance: float) -> np.ndarray:
    """COLMAP's FindBestMatchesOneWayBruteForce, transcribed loop for loop."""
    out = np.full(dots.shape[0], -1)
    for i1 in range(dots.shape[0]):
        best_idx, best, second = -1, np.float32(0), np.float32(0)
        for i2 in range(dots.shape[1]):
            d = dots[i1, i2]
            if d > best:
                best_idx, second, best = i2, best, d
            elif d > second:
                second = d
        if best_idx == -1:
            continue
        inv = np.float32(1.0 / SQ_DESCRIPTOR_NORM)
        best_dist = _acosf(min(inv * best, np.float32(1)))
        second_dist = _acosf(min(inv * second, np.float32(1)))
        if best_dist > np.float32(max_distance) or best_dist >= np.float32(max_ratio) * second_dist:
            continue
        out[i1] = best_idx
    return out


def _matches_reference(d1, d2, max_ratio=0.8, max_distance=0.7, cross_check=True) -> np.ndarray:
    dots = d1.astype(np.int64) @ d2.astype(np.int64).T  # exact integers
    m12 = _one_way_reference(dots.astype(np.float32), max_ratio, max_distance)
    if cross_check:
        m21 = _one_way_reference(dots.T.astype(np.float32), max_ratio, max_distance)
        keep = [(i, j) for i, j in enumerate(m12) if j >= 0 and m21[j] == i]
    else:
        keep = [(i, j) for i, j in enumerate(m12) if j >= 0]
    return np.array(keep, np.uint32).reshape(-1, 2)


def _descriptors(rng, n: int, dup_from: np.ndarray | None = None) -> np.ndarray:
    """RootSIFT-like uint8 descriptors (unit norm at 512), some copied from
    ``dup_from`` with small noise (true matches) and some exact duplicates (ties)."""
    d = rng.gamma(0.6, 1.0, (n, 128))
    d = np.sqrt(d / d.sum(1, keepdims=True))
    d = np.minimum(255, np.round(512 * d)).astype(np.uint8)
    if dup_from is not None and len(dup_from):
        k = min(n // 2, len(dup_from))
        noisy = dup_from[:k].astype(np.int64) + rng.integers(-3, 4, (k, 128))
        d[:k] = np.clip(noisy, 0, 255).astype(np.uint8)
        if n > k + 2:
            d[k] = d[k + 1]  # two identical features: a tie for every partner
    return d


def test_angles_are_libms_acosf_of_every_dot_product():
    """The distance and ratio tests compare the angles COLMAP computes (libm's
    acosf in float32), for every dot product that can occur: numpy's float32
    arccos differs from it in the last bit on about a third of them."""
    table = angle_table()
    inv = np.float32(1.0 / SQ_DESCRIPTOR_NORM)
    dots = np.arange(len(table), dtype=np.float32)
    ref = np.array([_acosf(v) for v in np.minimum(inv * dots, np.float32(1))], np.float32)
    np.testing.assert_array_equal(table, ref)
    assert table[-1] == 0 and table[0] == np.float32(np.pi / 2)


def test_best_two_finds_the_first_best_and_the_second_value_of_rows_and_columns():
    rng = np.random.default_rng(0)
    # few distinct values: ties everywhere; widths not a multiple of the lanes; zero rows
    dots = rng.integers(0, 6, (3, 37, 53)).astype(np.float32)
    dots[1, 5] = 0.0
    dots[2, :, 7] = 0.0
    K, n1, m = dots.shape
    out = [np.empty((K, n1), np.float32), np.empty((K, n1), np.float32), np.empty((K, n1), np.int32),
           np.empty((K, m), np.float32), np.empty((K, m), np.float32), np.empty((K, m), np.int32)]
    best_two(dots, *out)
    rb, rs, ri, cb, cs, ci = out
    srt = np.sort(dots, 2)
    np.testing.assert_array_equal(rb, srt[..., -1])
    np.testing.assert_array_equal(rs, srt[..., -2])
    np.testing.assert_array_equal(ri, np.where(rb > 0, np.argmax(dots, 2), -1))
    srt = np.sort(dots, 1)
    np.testing.assert_array_equal(cb, srt[:, -1])
    np.testing.assert_array_equal(cs, srt[:, -2])
    np.testing.assert_array_equal(ci, np.where(cb > 0, np.argmax(dots, 1), -1))
    assert ri[1, 5] == -1 and ci[2, 7] == -1


@pytest.mark.parametrize("cross_check", [True, False])
def test_matches_are_colmaps_brute_force_rule_on_ties_and_odd_sizes(cross_check):
    rng = np.random.default_rng(1)
    base = _descriptors(rng, 90)
    views = [base, _descriptors(rng, 70, base), _descriptors(rng, 1, base), _descriptors(rng, 0),
             _descriptors(rng, 130, base), base.copy()]
    pairs = np.array([(i, j) for i in range(len(views)) for j in range(len(views)) if i != j])
    # small blocks: a view's partners split over several chunks
    got = match_views(views, pairs, cross_check=cross_check, block_values=20_000)
    for (i, j), m in zip(pairs, got):
        ref = _matches_reference(views[i], views[j], cross_check=cross_check)
        np.testing.assert_array_equal(m, ref, err_msg=f"pair {i}-{j}")
    # identical views (no feature repeated within one): every feature matches itself
    m = got[[tuple(p) for p in pairs.tolist()].index((0, 5))]
    np.testing.assert_array_equal(m, np.repeat(np.arange(90, dtype=np.uint32)[:, None], 2, axis=1))


def test_matches_do_not_depend_on_threads_or_block_size():
    rng = np.random.default_rng(2)
    base = _descriptors(rng, 300)
    views = [_descriptors(rng, n, base) for n in (300, 250, 280, 120, 310)]
    pairs = np.array([(i, j) for i in range(5) for j in range(i + 1, 5)])
    one = match_views(views, pairs, threads=1)
    for threads, block in ((2, 1 << 24), (2, 50_000), (3, 1)):
        other = match_views(views, pairs, threads=threads, block_values=block)
        assert all(np.array_equal(a, b) for a, b in zip(one, other))
    assert sum(len(m) for m in one) > 100


def test_pairs_are_taken_once_in_their_first_orientation():
    from gs2e.sfm.colmap_sfm import unique_pairs

    assert unique_pairs([(1, 2), (3, 3), (52, 1), (2, 1), (1, 52), (2, 3)]) == [(1, 2), (52, 1), (2, 3)]
    assert unique_pairs([]) == []


@pytest.fixture(scope="module")
def fern_features(tmp_path_factory):
    """A COLMAP database with gs2e's SIFT features of four llff_fern photos."""
    import pycolmap

    from gs2e.sfm import colmap_sfm
    from gs2e.sfm.settings import SfmSettings

    src = shared_data("llff_fern", "images")
    names = sorted(p.name for p in src.iterdir())[:4]
    db = tmp_path_factory.mktemp("fern") / "features.db"
    colmap_sfm._extract(db, src, names, SfmSettings.defaults(), 2, pycolmap.CameraMode.SINGLE, "SIMPLE_RADIAL")
    return db


@pytest.mark.parametrize("matcher", ["exhaustive", "sequential"])
def test_gemm_matching_leaves_the_database_colmaps_brute_force_matcher_leaves(fern_features, tmp_path, matcher):
    """Real features of four llff_fern photos: matches and verified two-view
    geometries equal those of COLMAP's own brute-force matcher, for both pairings."""
    import pycolmap

    from gs2e.sfm import colmap_sfm
    from gs2e.sfm.settings import SfmSettings

    cfg = SfmSettings.defaults(sequential_overlap=1)  # sequential: not every pair
    theirs, ours = tmp_path / "colmap.db", tmp_path / "gs2e.db"
    shutil.copy(fern_features, theirs)
    shutil.copy(fern_features, ours)
    mopts = pycolmap.FeatureMatchingOptions()
    mopts.num_threads = 1
    mopts.sift.cpu_brute_force_matcher = True
    vopts = pycolmap.TwoViewGeometryOptions()
    vopts.ransac.random_seed = 3
    if matcher == "exhaustive":
        pycolmap.match_exhaustive(theirs, matching_options=mopts, verification_options=vopts,
                                  device=pycolmap.Device.cpu)
    else:
        pycolmap.match_sequential(theirs, matching_options=mopts, verification_options=vopts,
                                  pairing_options=colmap_sfm._pairing_options(cfg, 1), device=pycolmap.Device.cpu)
    timings = {}
    colmap_sfm._match_gemm(ours, matcher, cfg, 2, 1, 3, timings)
    assert set(timings) == {"descriptor_matching", "verification"}
    a, b = pycolmap.Database.open(str(theirs)), pycolmap.Database.open(str(ours))
    try:
        ids = sorted(im.image_id for im in a.read_all_images())
        n_inliers, n_pairs = 0, 0
        for k, i in enumerate(ids):
            for j in ids[k + 1:]:
                assert a.exists_matches(i, j) == b.exists_matches(i, j)
                if not a.exists_matches(i, j):
                    continue
                n_pairs += 1
                np.testing.assert_array_equal(np.asarray(b.read_matches(i, j)), np.asarray(a.read_matches(i, j)))
                ga, gb = a.read_two_view_geometry(i, j), b.read_two_view_geometry(i, j)
                assert ga.config == gb.config
                np.testing.assert_array_equal(np.asarray(gb.inlier_matches), np.asarray(ga.inlier_matches))
                n_inliers += len(ga.inlier_matches)
        assert n_pairs == (6 if matcher == "exhaustive" else 3)
        assert n_inliers > 100  # the photos overlap: real matches were compared
    finally:
        a.close()
        b.close()
