"""Every exporter, read back the way the target method's own loader reads it
(re-implemented here from the loaders: r00tman/EventNeRF data_loader_split.py,
iCVTEAM/E2NeRF load_blender.py + run_nerf_exp.py, deguchihiroyuki/E2GS
readBlurNerfSyntheticInfo, uzh-rpg/EvDeblurNeRF data/loader*.py,
WU-CVGL/IncEventGS ReplicaEventDataset, lanpokn/Event-3DGS readColmapSceneInfo),
checking poses, intrinsics and event counts against the gs2e source.

The source is the shared tiny pipeline with its events re-simulated over the
whole trajectory (the tiny run simulates only 30 ms, less than a frame interval).
"""

from __future__ import annotations

import glob
import json
import os
import struct

import numpy as np
import pytest

from gs2e.common.errors import InputError
from gs2e.export.run import export_trajectory
from gs2e.export.settings import ExportSettings
from gs2e.export.source import TrajectorySource
from tests.conftest import run_cli
from tests.test_export_loaders import (EVENTNERF_ARG_DEFAULTS, e2gs_test_entries, e2nerf_test_entries,
                                       event3dgs_index_range, eventnerf_config, eventnerf_samplers,
                                       evdeblurnerf_edi_events, evdeblurnerf_event_times, inceventgs_chunks)

TRAJ = "mini00_medium"
DEFAULTS = {"formats": [], "eventnerf_fit": "pad", "eventnerf_holdout_every": 4, "eventnerf_winsize": None,
            "e2nerf_loader": "e2gs", "evdeblurnerf_llffhold": 4, "evdeblurnerf_pose_rate_hz": 1000.0,
            "event3dgs_intensity": "integrate", "inceventgs_jpeg_quality": 95}


@pytest.fixture(scope="session")
def export_scene(tiny_pipeline, tmp_path_factory):
    return export_tree(tiny_pipeline, tmp_path_factory.mktemp("export_tree"))


def export_tree(tiny_pipeline, base):
    """``base``/tiny: results/tiny with events over the whole trajectory and their windows."""
    from gs2e.config import load_section

    wd, _ = tiny_pipeline
    src = wd / "results" / "tiny"
    dst = base / "tiny"
    dst.mkdir()
    for d in ("sfm", "splat", "trajectories", "frames"):
        (dst / d).symlink_to(src / d, target_is_directory=True)
    events = load_section("events", json.dumps({"model": "ideal", "theta_on": 0.3, "theta_off": 0.3,
                                                "preview": False, "max_duration_s": None}))
    run_cli("events", "--model", str(src / "splat"), "--trajectory", str(src / "trajectories" / f"{TRAJ}.npz"),
            "-o", str(dst / "events" / TRAJ), "--seed", "7", "--threads", "2",
            "--config-json", json.dumps(events), check=True)
    run_cli("windows", "--frames", str(dst / "frames" / TRAJ), "--events", str(dst / "events" / TRAJ),
            "--out", str(dst / "windows" / f"{TRAJ}.parquet"), check=True)
    return dst


@pytest.fixture(scope="session")
def source(export_scene):
    return TrajectorySource(export_scene, TRAJ)


def _export(export_scene, tmp_path_factory, fmt, **over):
    out = tmp_path_factory.mktemp(f"exp_{fmt}") / "scene"
    man = export_trajectory(export_scene, TRAJ, fmt, out, ExportSettings.defaults(**{**DEFAULTS, **over}),
                            scene_id="tiny")
    assert json.loads((out / "gs2e_export.json").read_text())["format"] == fmt
    return out, man


def _counts_in(t_us, a, b):
    return int(np.searchsorted(t_us, b, "left") - np.searchsorted(t_us, a, "left"))


# ---------------------------------------------------------------- EventNeRF
def _parse_txt(path, shape):
    # data_loader_split.parse_txt
    return np.array([float(x) for x in open(path).read().split()]).reshape(shape).astype(np.float32)


def test_eventnerf_reads_back(export_scene, source, tmp_path_factory):
    out, man = _export(export_scene, tmp_path_factory, "eventnerf")
    cfg = {**EVENTNERF_ARG_DEFAULTS, **eventnerf_config((out / "eventnerf.txt").read_text())}
    assert cfg["is_cycled"] == "False" and int(cfg["winsize"]) == man["winsize"] >= 1
    norm = man["normalisation"]
    fit = man["sensor_fit"]
    ev_all = source.events()
    for split in ("train", "validation", "test"):
        d = out / split
        poses = sorted(glob.glob(str(d / "pose" / "*.txt")))
        intr = sorted(glob.glob(str(d / "intrinsics" / "*.txt")))
        rgbs = sorted(glob.glob(str(d / "rgb" / "*.png")))
        evf = sorted(glob.glob(str(d / "events" / "*.npz")))
        assert len(evf) == 1 and len(poses) == len(intr) == len(rgbs) >= 3
        frames = np.array(man["splits"][split]["gs2e_frames"])
        assert len(frames) == len(poses)
        import imageio.v2 as imageio
        assert imageio.imread(rgbs[0]).shape[:2] == (260, 346)  # H, W = 260, 346 in the loader
        for k, i in enumerate(frames):
            c2w = _parse_txt(poses[k], (4, 4)).astype(np.float64)
            assert np.linalg.norm(c2w[:3, 3]) < 1.0  # NeRF++: cameras inside the unit sphere
            back = c2w.copy()
            back[:3, 3] = back[:3, 3] / norm["scale"] - np.array(norm["translate"])
            np.testing.assert_allclose(back, source.c2w([i])[0], atol=1e-5)
            K = _parse_txt(intr[k], (4, 4))
            K = np.concatenate((K, np.zeros((1, 4), np.float32)), 0)  # loader: unity distortion
            Ks = source.K(i)
            np.testing.assert_allclose([K[0, 0], K[1, 1], K[0, 2], K[1, 2]],
                                       [Ks[0, 0], Ks[1, 1], Ks[0, 2] - fit["offset_x"],
                                        Ks[1, 2] - fit["offset_y"]], rtol=1e-6)
        z = np.load(evf[0])
        xs, ys, ts, ps = z["x"], z["y"], z["t"], z["p"]
        assert set(np.unique(ps[:-1])) <= {-1, 1} and ps[-1] == 0 and ts.min() >= 0  # closing p = 0 event
        assert xs.max() < 346 and ys.max() < 260
        t_src = source.frames["t_us"].to_numpy()[frames]
        sel = (ev_all.t >= t_src[0]) & (ev_all.t < t_src[-1])
        src_t, src_x = ev_all.t[sel], ev_all.x[sel].astype(np.int64) - fit["offset_x"]
        src_p = ev_all.p[sel].astype(np.int64) * 2 - 1
        assert len(ts) == len(src_t) + 1 and ps.sum() == src_p.sum()
        # the loader as ddp_train_nerf.py calls it (L440-451) with the exported config
        N = len(poses)
        skip = int(cfg["trainskip"] if split == "train" else cfg["testskip"])
        max_win = int(cfg["winsize"]) if split == "train" else 1
        sizes = range(1, max_win + 1) if split == "train" else [1]  # use_random_window_len: 1 .. winsize
        samplers = [eventnerf_samplers(ts, N, skip, max_win, w) for w in sizes]
        assert all(len(s) > 0 for s in samplers), (split, skip, max_win, N)
        assert [i for i, _, _ in samplers[0]] == list(range(1 + max_win, N))
        assert frames[1 + max_win:].tolist() == man["splits"][split]["loader_views"]
        for w, sampler in zip(sizes, samplers):
            for i, a, b in sampler:  # exactly gs2e's events of [t_{i-w}, t_i)
                lo, hi = np.searchsorted(src_t, [t_src[i - w], t_src[i]])
                assert (a, b) == (lo, hi)
                np.testing.assert_array_equal(xs[a:b], src_x[lo:hi])
                np.testing.assert_array_equal(ps[a:b], src_p[lo:hi])
                if w == 1:  # the inter-frame windows from frames[i - 1] (excluded) to frames[i]
                    span = np.arange(frames[i - 1] + 1, frames[i] + 1)
                    assert b - a == source.window_counts("inter", span).sum()
    # validation / test views are held out of training (every one a sampler)
    held = man["heldout_frames"]
    assert held and set(held).isdisjoint(man["splits"]["train"]["gs2e_frames"])
    assert man["splits"]["validation"]["loader_views"] == man["splits"]["test"]["loader_views"] == held


def test_eventnerf_sensor_size_is_an_error_by_default(export_scene, tmp_path):
    proc = run_cli("export", "--scene-dir", str(export_scene), "--trajectory", TRAJ, "--format", "eventnerf",
                   "--out", str(tmp_path / "x"))
    assert proc.returncode == 2
    err = [ln for ln in proc.stderr.splitlines() if "error:" in ln]
    assert len(err) == 1 and "346x260" in err[0] and "128x96" in err[0]
    assert not (tmp_path / "x").exists() and not list(tmp_path.iterdir())


# ---------------------------------------------------------------- E2NeRF / E2GS
def test_e2nerf_e2gs_reads_back(export_scene, source, tmp_path_factory):
    import imageio.v2 as imageio
    import torch

    out, man = _export(export_scene, tmp_path_factory, "e2nerf")
    meta = json.load(open(out / "transform_train.json"))
    H, W = source.height, source.width
    focal = .5 * W / np.tan(.5 * float(meta["camera_angle_x"]))  # load_blender.py
    assert focal == pytest.approx(source.K(0)[0, 0], rel=1e-9)
    views_e2nerf = meta["frames"][0:200:2]   # load_blender.py
    views_e2gs = meta["frames"][::2]          # readNCamerasFromTransforms
    assert views_e2nerf == views_e2gs
    frames = man["gs2e_frames"]
    assert len(views_e2gs) == len(frames)
    events = torch.load(out / "events.pt")
    assert tuple(events.shape) == (len(frames), 4, H, W)
    ev_all = source.events()
    w = source.windows
    for num, (view, i) in enumerate(zip(views_e2gs, frames)):
        img = imageio.imread(out / "train" / f"r_{2 * num}.png")   # ./train/r_{num}.png, num = 0, 2, ...
        assert img.shape[:2] == (H, W)
        assert os.path.exists(os.path.join(out, view["file_path"] + ".png"))  # E2GS: file_path + ext
        ea, eb = int(w["exp_t0_us"].iloc[i]), int(w["exp_t1_us"].iloc[i])
        for j in range(5):
            c2w = np.array(view["transform_matrix"])[j * 4 + 1]
            c2w[:3, 1:3] *= -1  # E2GS: OpenGL -> COLMAP axes
            np.testing.assert_allclose(c2w, source.poses_at([ea + j * (eb - ea) / 4])[0], atol=1e-9)
        # bins: ON - OFF between consecutive exposure poses; their sum is the exposure window's
        sel = slice(int(w["exp_i0"].iloc[i]), int(w["exp_i1"].iloc[i]))
        net = np.zeros(H * W)
        np.add.at(net, ev_all.y[sel].astype(int) * W + ev_all.x[sel], ev_all.p[sel] * 2.0 - 1)
        np.testing.assert_array_equal(events[num].sum(0).numpy().ravel(), net)
        assert events[num][0].view(H, W).shape == (H, W)  # event_loss_call's view
    test = json.load(open(out / "transform_test.json"))["frames"]
    # E2GS keeps frames[::2]: exactly gs2e's test views, in order, with their images
    views = e2gs_test_entries(test)
    assert [v["gs2e_frame"] for v in views] == list(frames)
    for v, i in zip(views, frames):
        assert os.path.exists(os.path.join(out, v["file_path"] + ".png"))
        for j in range(5):  # readNCamerasFromTransforms reads entries 1, 5, .., 17
            c2w = np.array(v["transform_matrix"])[j * 4 + 1]
            c2w[:3, 1:3] *= -1
            np.testing.assert_allclose(c2w, source.c2w([i])[0], atol=1e-12)
    # E2NeRF reads every entry with ./test/r_{count}.png: each view twice, same images
    for num, fr in enumerate(e2nerf_test_entries(test)):
        c2w = np.array(fr["transform_matrix"][1])   # E2NeRF tests with entry 1
        c2w[:3, 1:3] *= -1
        np.testing.assert_allclose(c2w, source.c2w([frames[num // 2]])[0], atol=1e-12)
        np.testing.assert_array_equal(imageio.imread(out / "test" / f"r_{num}.png"),
                                      source.image("rgb", frames[num // 2]))
    # render_novel.py sizes its novel views by images/r_0.png (dataset_readers.py L505)
    assert imageio.imread(out / "images" / "r_0.png").shape[:2] == (H, W)
    import pycolmap
    rec = pycolmap.Reconstruction(str(out / "sparse" / "0"))
    assert rec.num_points3D() == len(source.points()[0]) > 0
    assert any("E2NeRF" in m for m in man["warnings"])  # 128x96: E2GS only, said so


def test_e2nerf_strict_loader_names_the_hard_coded_size(export_scene, tmp_path):
    with pytest.raises(InputError, match="800x800"):
        export_trajectory(export_scene, TRAJ, "e2nerf", tmp_path / "x",
                          ExportSettings.defaults(**{**DEFAULTS, "e2nerf_loader": "e2nerf"}))
    assert not (tmp_path / "x").exists()


# ---------------------------------------------------------------- EvDeblurNeRF
def test_evdeblurnerf_reads_back(export_scene, source, tmp_path_factory):
    import h5py
    from scipy.interpolate import interp1d
    from scipy.spatial.transform import Rotation, Slerp

    out, man = _export(export_scene, tmp_path_factory, "evdeblurnerf")
    hold = man["llffhold"]
    imgs = sorted(f for f in os.listdir(out / "images_1") if f.endswith("png"))
    frames = man["gs2e_frames"]
    assert len(imgs) == len(frames)
    poses_arr = np.load(out / "poses_bounds.npy")
    poses = poses_arr[:, :-2].reshape([-1, 3, 5])
    bds = poses_arr[:, -2:]
    assert np.allclose(np.linalg.det(poses[:, :3, :3]), 1.0)  # _is_pure_rotation_matrix
    gl = np.concatenate([poses[..., 1:2], -poses[..., 0:1], poses[..., 2:]], -1)  # load_poses
    H, W, focal = gl[0, :3, -1]
    assert (H, W) == (source.height, source.width) and focal == pytest.approx(source.K(0)[0, 0])
    for k, i in enumerate(frames):
        c2w = np.eye(4)
        c2w[:3, :4] = gl[k, :, :4]
        c2w[:3, 1:3] *= -1  # OpenGL -> OpenCV
        np.testing.assert_allclose(c2w, source.c2w([i])[0], atol=1e-12)
    assert (bds[:, 0] > 0).all() and (bds[:, 1] > bds[:, 0]).all()
    tms = np.load(out / "images_1" / "timestamps.npz")
    sharp = tms["timestamps_start"] == tms["timestamps_end"]
    assert (np.nonzero(sharp)[0] == np.arange(0, len(imgs), hold)).all()  # llffhold test views
    assert (tms["timestamps_start"] > 0).all()                                # EDI prior's assertion
    origin = man["time_origin_us"]
    np.testing.assert_array_equal(tms["timestamps"] + origin, source.frames["t_us"].to_numpy()[frames])
    f = h5py.File(out / "events.h5", "r")
    ev = {k: f[k][:] for k in "xytp"}
    txt = eventnerf_config((out / "evdeblurnerf.txt").read_text())
    t_us = evdeblurnerf_event_times(ev["t"], txt["events_tms_unit"])
    assert t_us.dtype == np.int64
    all_t = np.load(out / "all_timestamps.npy")
    keep = (t_us >= all_t.min()) & (t_us <= all_t.max())  # loader_events.py L193
    assert keep.all() and set(np.unique(ev["p"])) == {0, 1}
    np.testing.assert_array_equal(t_us + origin, source.events(int(t_us[0] + origin), int(t_us[-1] + origin) + 1).t)
    # training batches: events with a successor at their pixel, drop_last (run_nerf.py L89-90)
    n_rand = int(txt.get("events_N_rand", 2048))
    assert man["n_event_samples"] >= n_rand
    w = source.windows
    for k, i in enumerate(frames):
        if sharp[k]:
            continue
        n = _counts_in(t_us, tms["timestamps_start"][k], tms["timestamps_end"][k])
        assert n == int(w["exp_i1"].iloc[i] - w["exp_i0"].iloc[i])
        # the EDI prior's closed window [start, exp_t1_us - 0.5] is gs2e's exposure window
        a, b = evdeblurnerf_edi_events(t_us, tms["timestamps_start"][k], tms["timestamps_end"][k])
        assert b - a == n
    # the loader interpolates all_poses_bounds (Slerp + cubic) at event times
    allp = np.load(out / "all_poses_bounds.npy")[:, :-2].reshape(-1, 3, 5)[:, :3, :4]
    rot = Slerp(all_t, Rotation.from_matrix(allp[:, :3, :3]))
    trans = interp1d(all_t, allp[:, :3, 3], axis=0, kind="cubic")
    tq = tms["timestamps"].astype(np.float64)
    llff = np.concatenate([rot(tq).as_matrix(), trans(tq)[..., None]], -1)
    np.testing.assert_allclose(llff, poses[:, :3, :4], atol=1e-6)


# ---------------------------------------------------------------- IncEventGS
def test_inceventgs_reads_back(export_scene, source, tmp_path_factory):
    import yaml

    out, man = _export(export_scene, tmp_path_factory, "inceventgs")
    img_files = sorted(glob.glob(f"{out}/images/*.jpg"))
    gt_poses = np.loadtxt(out / "traj.txt")
    poses_ts = np.loadtxt(out / "poses_ts.txt")
    frames = np.array(man["gs2e_frames"])
    assert len(img_files) == len(gt_poses) == len(poses_ts) == len(frames)
    np.testing.assert_allclose(gt_poses.reshape(-1, 4, 4), source.c2w(frames), atol=1e-12)
    raw = np.load(out / "event_threshold_0.1" / "gray_events_data.npy")
    assert set(np.unique(raw[:, 3])) <= {-1.0, 1.0}
    ev_all = source.events()
    w = source.windows.iloc[frames[1:]]
    for numpy2 in (True, False):  # exactly gs2e's windows, whichever NumPy the method runs on
        chunks = inceventgs_chunks(raw, poses_ts, numpy2)
        assert len(chunks) == len(frames) - 1  # __len__ = num_frames - 1: every image has a sample
        for chunk, (_, r) in zip(chunks, w.iterrows()):
            a, b = int(r["inter_i0"]), int(r["inter_i1"])
            np.testing.assert_array_equal(chunk[:, 0], ev_all.x[a:b])
            np.testing.assert_array_equal(chunk[:, 3], ev_all.p[a:b] * 2.0 - 1)
    cfg = yaml.safe_load(open(out / "gs2e_inceventgs.yaml"))
    K = source.K(0)
    assert (cfg["cam"]["H"], cfg["cam"]["W"]) == (source.height, source.width)
    assert [cfg["cam"][k] for k in ("fx", "fy", "cx", "cy")] == [K[0, 0], K[1, 1], K[0, 2], K[1, 2]]
    assert cfg["data"]["training_end_index"] == len(frames)


# ---------------------------------------------------------------- Event-3DGS
def _read_colmap_bin(model):
    """cameras.bin / images.bin as colmap_loader.read_*_binary parse them."""
    cams, imgs = {}, {}
    with open(model / "cameras.bin", "rb") as fh:
        for _ in range(struct.unpack("<Q", fh.read(8))[0]):
            cid, model_id, w, h = struct.unpack("<iiQQ", fh.read(24))
            assert model_id == 1  # PINHOLE
            cams[cid] = (w, h, struct.unpack("<4d", fh.read(32)))
    with open(model / "images.bin", "rb") as fh:
        for _ in range(struct.unpack("<Q", fh.read(8))[0]):
            iid, *qt, cid = struct.unpack("<idddddddi", fh.read(64))
            name = b""
            while (c := fh.read(1)) != b"\x00":
                name += c
            n2d = struct.unpack("<Q", fh.read(8))[0]
            fh.read(24 * n2d)
            imgs[name.decode()] = (np.array(qt[:4]), np.array(qt[4:]), cid)
    return cams, imgs


def _qvec2rotmat(q):
    w, x, y, z = q
    return np.array([[1 - 2 * y * y - 2 * z * z, 2 * x * y - 2 * w * z, 2 * z * x + 2 * w * y],
                     [2 * x * y + 2 * w * z, 1 - 2 * x * x - 2 * z * z, 2 * y * z - 2 * w * x],
                     [2 * z * x - 2 * w * y, 2 * y * z + 2 * w * x, 1 - 2 * x * x - 2 * y * y]])


def test_event3dgs_reads_back(export_scene, source, tmp_path_factory):
    import imageio.v2 as imageio

    from gs2e.export.event3dgs import LogSignal

    out, man = _export(export_scene, tmp_path_factory, "event3dgs")
    cams, imgs = _read_colmap_bin(out / "sparse" / "0")
    names = sorted(imgs)
    for folder in ("images", "images_event", "images_blurry", "renders"):
        assert sorted(os.listdir(out / folder)) == names  # one-to-one with COLMAP names
    frames = man["gs2e_frames"]
    assert len(names) == len(frames) >= 7
    assert len(event3dgs_index_range(len(names))) > 0  # train.py draws a training pair
    assert man["heldout_frames"] == [frames[k] for k in (5, 25, 45, 65, 85) if k < len(frames)]
    for name, i in zip(names, frames):
        q, t, cid = imgs[name]
        R = np.transpose(_qvec2rotmat(q))  # readColmapCameras: R = qvec2rotmat(q).T, T = tvec
        w2c = np.eye(4)
        w2c[:3, :3], w2c[:3, 3] = R.T, t
        np.testing.assert_allclose(np.linalg.inv(w2c), source.c2w([i])[0], atol=1e-9)
        w, h, (fx, fy, cx, cy) = cams[cid]
        K = source.K(i)
        assert (w, h) == (source.width, source.height)
        np.testing.assert_allclose([fx, fy, cx, cy], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    # consecutive event images differ by the events between the views: on well-exposed
    # pixels the log-signal change is (ON - OFF) x threshold up to 8-bit rounding
    from gs2e.common.color import srgb_to_linear
    from gs2e.events.io import read_h5
    from gs2e.events.represent import event_frame

    _, attrs = read_h5(source.events_file, (0, 0))
    sig = LogSignal(attrs, (source.height, source.width), "x")
    t = source.frames["t_us"].to_numpy()
    agree, total = 0, 0
    for a, b, na, nb in zip(frames[:-1], frames[1:], names[:-1], names[1:]):
        va = imageio.imread(out / "images_event" / na)[..., 0]
        vb = imageio.imread(out / "images_event" / nb)[..., 0]
        dg = sig.G(srgb_to_linear(vb / 255.0)) - sig.G(srgb_to_linear(va / 255.0))
        c = event_frame(source.events(int(t[a]), int(t[b])), (source.height, source.width))
        expect = c[1] * sig.step_on - c[0] * sig.step_off
        ok = (va > 30) & (va < 250) & (vb > 30) & (vb < 250)
        agree += int((np.abs(dg - expect)[ok] < 0.5 * sig.step_on[ok]).sum())
        total += int(ok.sum())
    assert total > 0 and agree / total > 0.99
    assert man["n_events"] == int(source.window_counts("inter", frames[1:]).sum()) > 0


def test_export_needs_covered_frames(tiny_pipeline, tmp_path):
    """The tiny run's 30 ms of events cover no pair of frames: a clear error, no output."""
    wd, _ = tiny_pipeline
    proc = run_cli("export", "--scene-dir", str(wd / "results" / "tiny"), "--trajectory", TRAJ,
                   "--format", "inceventgs", "--out", str(tmp_path / "x"))
    assert proc.returncode == 2 and "fewer than two consecutive frames" in proc.stderr
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------- gs2e.data
def _docs_example() -> str:
    """The DataLoader example of docs/export.md (moved there from the README)."""
    from tests.conftest import REPO

    text = (REPO / "docs" / "export.md").read_text()
    block = text.split("## A torch Dataset", 1)[1].split("```python\n", 1)[1].split("```", 1)[0]
    assert "EventWindowDataset" in block and "DataLoader" in block
    return block


def test_docs_dataloader_example_runs(export_scene, source):
    code = _docs_example().replace('"results"', repr(str(export_scene.parent)))
    ns: dict = {}
    exec(compile(code, "docs/export.md", "exec"), ns)
    B = ns["voxels"].shape[0]
    assert tuple(ns["voxels"].shape) == (B, 5, source.height, source.width)
    assert tuple(ns["rgb"].shape) == (B, 3, source.height, source.width)
    assert tuple(ns["c2w"].shape) == (B, 4, 4) and tuple(ns["K"].shape) == (B, 3, 3)
    assert len(ns["ds"]) == int(source.windows["inter_covered"].sum())


def test_dataset_items_match_the_source(export_scene, source):
    import pandas as pd
    import torch

    from gs2e.data import EventWindowDataset, collate_windows
    from gs2e.events.represent import voxel_grid

    ev = source.events()
    raw = EventWindowDataset(export_scene.parent, representation="raw", load=("depth",))
    item = raw[len(raw) // 2]
    w = source.windows.iloc[item["frame"]]
    a, b = int(w["inter_i0"]), int(w["inter_i1"])
    arr = item["events"]
    assert arr.dtype.names == ("x", "y", "t", "p") and len(arr) == b - a == item["n_events"]
    np.testing.assert_array_equal(arr["t"], ev.t[a:b])
    np.testing.assert_array_equal(arr["x"], ev.x[a:b])
    np.testing.assert_array_equal(arr["p"], ev.p[a:b])
    np.testing.assert_allclose(item["c2w"].numpy(), source.c2w([item["frame"]])[0])
    np.testing.assert_allclose(item["depth"][0].numpy(), source.depth(item["frame"]))
    batch = collate_windows([raw[0], raw[1]])
    assert isinstance(batch["events"], list) and batch["depth"].shape[0] == 2
    # voxel grids are gs2e.events.represent's; exposure windows have their own count
    vox = EventWindowDataset(export_scene.parent, window="exposure", n_bins=3, load=())
    it = vox[0]
    w = source.windows.iloc[it["frame"]]
    sub = source.events(int(w["exp_t0_us"]), int(w["exp_t1_us"]))
    expect = voxel_grid(sub, (source.height, source.width), 3, int(w["exp_t0_us"]), int(w["exp_t1_us"]))
    assert torch.equal(it["events"], torch.from_numpy(expect))
    assert len(vox) == int(source.windows["exp_covered"].sum())
    # a summary.parquet selection; an empty one is an empty dataset
    sel = pd.DataFrame({"scene_id": ["tiny"], "trajectory": [TRAJ]})
    assert len(EventWindowDataset(export_scene.parent, selection=sel, load=())) == len(raw)
    assert len(EventWindowDataset(export_scene.parent, selection=sel.iloc[:0], load=())) == 0
    with pytest.raises(InputError, match="windows"):
        EventWindowDataset(export_scene.parent, selection=pd.DataFrame(
            {"scene_id": ["tiny"], "trajectory": ["nope"]}))
