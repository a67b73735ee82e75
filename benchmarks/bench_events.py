"""Event-simulation throughput on the standard sequence.

Standard sequence: scikit-image's astronaut photo in grey (linear luminance),
panning and zooming, 346x260, 2400 fps, 0.2 s = 480 frames
(gs2e.events.synthetic.standard_sequence).

Measured per model / preset: pixel-frames per second and events per second
(wall clock, and per CPU-second x threads, since the machine may be shared),
the event statistics, an in-run baseline (a plain vectorised numpy
implementation of the same voltmeter model, written here) and the peak RSS of
the streaming pipeline (model + DSEC HDF5 writer + stats) at two sequence
lengths, each in a fresh process.

Whole command, side by side in one run (issue 11): the same 480 frames as
8-bit PNGs with timestamps, simulated by the official DVS-Voltmeter
(``main.py``, dvs346; read from a checkout given by ``--voltmeter-repo`` or the
GS2E_VOLTMETER_REPO variable, a git directory or a folder; it needs torch and
easydict: ``pip install -e .[bench]``) and by ``gs2e events`` (same frames,
``--encoding linear``, dvs346, no preview), each as a fresh process, wall
time including start-up and file I/O; event count and ON fraction of both,
and gs2e's own split of its run (reading frames, model, statistics, writing).
Without the official code that part is reported as not measured.

Reference figure (REFERENCE.md section 2): the public DVS-Voltmeter code runs
this kind of sequence at ~4.3 M pixel-frames/s on 2 cores (torch CPU).

Usage: python benchmarks/bench_events.py [--quick] [--voltmeter-repo PATH]
Writes benchmarks/results/bench_events.csv and bench_events.png; the last
printed line is the headline.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from gs2e.events.models import IdealModel, VoltmeterModel
from gs2e.events.presets import PRESETS, effective_threshold
from gs2e.events.settings import event_settings
from gs2e.events.synthetic import standard_sequence
from harness import REPO, clock, gs2e_env, parser, pyplot, report, save_plot, write_csv

PUBLIC_MPF = 4.3  # M pixel-frames/s of the public DVS-Voltmeter code (REFERENCE.md §2)
TARGET_MPF = 65.0


# ---------------------------------------------------------------- baseline
def numpy_voltmeter(ts, frames, preset, seed=0, theta=1.0):
    """Plain vectorised numpy implementation of the same model (polarity by the
    two-barrier probability, crossing of the polarity-conditioned drift
    diffusion by its end point + bridge, crossing time from the bridge's
    first-passage law, residual carried). Returns (n_events, n_on)."""
    rng = np.random.default_rng(seed)
    k1, k2, k3, k4, k5, k6 = preset.k
    sc, tu = preset.intensity_scale, preset.time_unit_us
    H, W = frames.shape[1:]
    res = np.zeros(H * W)
    n_ev = n_on = 0
    prev = frames[0].astype(np.float64).ravel() * sc
    for i in range(1, len(ts)):
        cur = frames[i].astype(np.float64).ravel() * sc
        t0, t1 = float(ts[i - 1]), float(ts[i])
        lbar = 0.5 * (prev + cur)
        mu = k1 * (cur - prev) / ((t1 - t0) / tu) / (lbar + k2) + k4 + k5 * lbar
        sg = k3 * np.sqrt(lbar) / (lbar + k2) + k6
        idx = np.arange(H * W)
        t = np.full(H * W, t0)
        v = res.copy()
        ev_t = []
        while idx.size:
            m, s_, vv = mu[idx], sg[idx], v[idx]
            a, b = theta - vv, theta + vv
            z = 2 * m / s_**2
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                pos = np.expm1(-z * b) / np.expm1(-z * (a + b))
                neg = np.exp(z * a) * np.expm1(z * b) / np.expm1(z * (a + b))
            p_on = np.where(z > 0, pos, neg)
            p_on = np.where(np.abs(z) * (a + b) < 1e-12, b / (a + b), p_on)
            on = rng.random(idx.size) < p_on
            eps = np.where(on, a, b)
            s = (t1 - t[idx]) / tu
            y = np.abs(m) * s + s_ * np.sqrt(s) * rng.standard_normal(idx.size)
            d = eps - y
            with np.errstate(over="ignore"):
                cross = (d <= 0) | (rng.random(idx.size) < np.exp(-2 * eps * np.maximum(d, 0) / (s_**2 * s)))
            nc = ~cross
            v[idx[nc]] = np.clip(np.where(on[nc], vv[nc] + y[nc], vv[nc] - y[nc]),
                                 -theta * (1 - 1e-9), theta * (1 - 1e-9))
            c = np.flatnonzero(cross)
            if c.size == 0:
                break
            drift = np.maximum(np.abs(d[c]) / s[c], 1e-300)
            U = rng.wald(eps[c] / drift, (eps[c] / s_[c]) ** 2)
            tau = s[c] * U / (s[c] + U)
            te = t[idx[c]] + tau * tu
            ev_t.append(te)
            n_on += int(on[c].sum())
            v[idx[c]] = 0.0
            t[idx[c]] = te
            idx = idx[c]
        if ev_t:
            tt = np.concatenate(ev_t)
            n_ev += tt.size
            np.argsort(tt, kind="stable")  # the events of a frame are sorted, like ours
        res = v
        prev = cur
    return n_ev, n_on


# ---------------------------------------------------------------- children
def child_memory(n_frames: int, out: str) -> None:
    """Streaming pipeline on n_frames of the standard sequence; prints JSON with
    the peak RSS."""
    import resource

    from gs2e.config import load_section
    from gs2e.events.frames import IterSource
    from gs2e.events.simulate import simulate_to_folder

    cfg = load_section("events", text=json.dumps({"preset": "dvs346", "preview": False,
                                                  "compression": "lzf"}))
    src = IterSource(standard_sequence(n_frames=n_frames), shape=(260, 346),
                     n_frames=n_frames, name="standard")
    st = simulate_to_folder(src, event_settings(cfg), out, seed=0)
    # VmHWM (peak RSS of this process image); ru_maxrss would include the
    # parent's RSS at fork time, which Linux keeps across exec
    try:
        with open("/proc/self/status") as fh:
            rss_mb = next(int(ln.split()[1]) for ln in fh if ln.startswith("VmHWM")) / 1024
    except (OSError, StopIteration):
        rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"n_frames": n_frames, "peak_rss_mb": rss_mb, "n_events": st["n_events"]}))


def measure_memory(n_frames: int) -> dict:
    import tempfile
    with tempfile.TemporaryDirectory() as d:
        r = subprocess.run([sys.executable, __file__, "--child-memory", str(n_frames),
                            str(Path(d) / "out")], capture_output=True, text=True, env=gs2e_env(REPO),
                           check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


# ---------------------------------------------------------------- whole command
def write_png_sequence(ts, frames, root: Path) -> Path:
    """The frames as 8-bit grey PNGs (linear values x 255) in the official
    code's layout: root/seq/{NNNN.png, info.txt ('path t_us' lines)}, plus
    root/ts.txt for gs2e."""
    import cv2

    seq = root / "seq"
    seq.mkdir(parents=True)
    lines = []
    for i, (t, f) in enumerate(zip(ts, frames)):
        p = seq / f"{i:04d}.png"
        cv2.imwrite(str(p), np.round(np.clip(f, 0, 1) * 255).astype(np.uint8))
        lines.append(f"{p} {int(t)}")
    (seq / "info.txt").write_text("\n".join(lines) + "\n")
    (root / "ts.txt").write_text("\n".join(str(int(t)) for t in ts) + "\n")
    return seq


def official_checkout(path: str | None, dest: Path) -> Path | None:
    """A working copy of the official DVS-Voltmeter code (from a folder or a
    bare git directory), or None."""
    if not path or not Path(path).exists():
        return None
    p = Path(path)
    if (p / "main.py").exists():
        return p
    dest.mkdir(parents=True)
    arch = subprocess.run(["git", "--git-dir", str(p), "archive", "HEAD"], capture_output=True,
                          check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=arch, check=True)
    return dest


def whole_commands(ts, frames, repo_path: str | None, reps: int = 3) -> dict:
    """Wall time of the official DVS-Voltmeter (once: ~20 s) and of `gs2e events`
    (best of ``reps`` fresh processes, as the start-up is part of it) on the same PNGs."""
    import shutil
    import tempfile

    out = {}
    with tempfile.TemporaryDirectory() as d:
        root = Path(d)
        seq = write_png_sequence(ts, frames, root / "in")
        env = gs2e_env(REPO)
        walls = []
        for _ in range(reps):
            shutil.rmtree(root / "gs2e", ignore_errors=True)
            with clock() as t:
                subprocess.run([sys.executable, "-m", "gs2e", "events", str(seq), "--timestamps",
                                str(root / "in" / "ts.txt"), "--encoding", "linear", "-o",
                                str(root / "gs2e"), "--set", "preset=dvs346", "--set",
                                "preview=false", "--seed", "1"], check=True, env=env,
                               capture_output=True, cwd=root)
            walls.append(t.wall_s)
        st = json.loads((root / "gs2e" / "stats.json").read_text())["stats"]
        out["gs2e"] = {"wall_s": min(walls), "wall_median_s": float(np.median(walls)),
                       "events": st["n_events"], "on_fraction": st["on_fraction"],
                       **{k: st[k] for k in ("simulate_s", "source_s", "model_s", "stats_s",
                                             "write_s", "close_s")}}
        code = official_checkout(repo_path, root / "official")
        if code is None:
            return out
        with clock() as t:
            r = subprocess.run([sys.executable, "main.py", "--camera_type", "DVS346", "--input_dir",
                                str(root / "in"), "--output_dir", str(root / "off")], cwd=code,
                               capture_output=True, text=True)
        wall = t.wall_s
        if r.returncode != 0:
            out["official_error"] = r.stderr.strip().splitlines()[-1] if r.stderr.strip() else "failed"
            return out
        ev = np.loadtxt(root / "off" / "seq.txt", ndmin=2)
        out["official"] = {"wall_s": wall, "events": int(len(ev)),
                           "on_fraction": float((ev[:, -1] > 0).mean()) if len(ev) else None}
    return out


# ---------------------------------------------------------------- main
def time_model(make, ts, frames, batch=32, reps=1):
    best = None
    for _ in range(reps):
        m = make()
        n = n_on = 0
        with clock() as t:
            for i in range(0, len(ts), batch):
                ev = m.process_batch(ts[i:i + batch], frames[i:i + batch])
                n += len(ev)
                n_on += int(ev.p.sum())
            ev = m.flush()
            n += len(ev)
            n_on += int(ev.p.sum())
        wall, cpu = t.wall_s, t.cpu_s
        if best is None or wall < best[0]:
            best = (wall, cpu, n, n_on)
    return best


def main() -> None:
    ap = parser(__doc__, quick="under 60 s")
    ap.add_argument("--child-memory", nargs=2, metavar=("N_FRAMES", "OUT"),
                    help="internal: the memory measurement's child process")
    ap.add_argument("--voltmeter-repo", default=os.environ.get(
        "GS2E_VOLTMETER_REPO", "/work/.mirror/Lynn0306+DVS-Voltmeter/repo"),
        help="checkout (or git dir) of the official DVS-Voltmeter code")
    args = ap.parse_args()
    if args.child_memory:
        child_memory(int(args.child_memory[0]), args.child_memory[1])
        return
    import numba

    threads = numba.get_num_threads()
    with clock() as gen:
        seq = list(standard_sequence())
        ts = np.array([t for t, _ in seq], np.int64)
        frames = np.stack([f for _, f in seq])
    t_gen = gen.wall_s
    H, W = frames.shape[1:]
    pf = (len(ts) - 1) * H * W
    load0 = os.getloadavg()[0]
    # compile / load the kernels outside the timings
    VoltmeterModel((H, W), preset="dvs346").simulate(ts[:3], frames[:3])
    IdealModel((H, W)).simulate(ts[:3], frames[:3])

    reps = 1 if args.quick else 3
    rows = []
    configs = [("voltmeter", name, lambda name=name: VoltmeterModel((H, W), preset=name, seed=1))
               for name in ("dvs346", "dvs240", "gs2e_paper")]
    configs.append(("voltmeter", "dvs346 two_barrier",
                    lambda: VoltmeterModel((H, W), preset="dvs346", seed=1, exit_law="two_barrier")))
    th_ideal = 0.2
    configs.append(("ideal", f"theta={th_ideal}",
                    lambda: IdealModel((H, W), theta_on=th_ideal, theta_off=th_ideal)))
    for model, preset, make in configs:
        wall, cpu, n, n_on = time_model(make, ts, frames, reps=reps)
        rows.append({"impl": "gs2e (numba)", "model": model, "preset": preset, "frames": len(ts),
                     "wall_s": wall, "cpu_s": cpu, "threads": threads, "events": n,
                     "on_fraction": n_on / max(n, 1), "mpf_per_s": pf / wall / 1e6,
                     "mpf_per_s_cpu_x_threads": pf / cpu * threads / 1e6,
                     "mev_per_s": n / wall / 1e6,
                     "eff_threshold_rel": (effective_threshold(PRESETS[preset.split()[0]], 1.0, 0.5)
                                           if model == "voltmeter" else float(np.expm1(th_ideal)))})
    # one thread: per-core throughput by CPU time, robust on a shared machine
    numba.set_num_threads(1)
    wall1, cpu1, n1, on1 = time_model(configs[0][2], ts, frames, reps=reps)
    numba.set_num_threads(threads)
    rows.append({"impl": "gs2e (numba, 1 thread)", "model": "voltmeter", "preset": "dvs346",
                 "frames": len(ts), "wall_s": wall1, "cpu_s": cpu1, "threads": 1, "events": n1,
                 "on_fraction": on1 / max(n1, 1), "mpf_per_s": pf / wall1 / 1e6,
                 "mpf_per_s_cpu_x_threads": pf / cpu1 / 1e6, "mev_per_s": n1 / wall1 / 1e6,
                 "eff_threshold_rel": effective_threshold(PRESETS["dvs346"], 1.0, 0.5)})
    # in-run baseline: plain numpy, same model, dvs346 (fewer frames in quick mode)
    nb = 49 if args.quick else len(ts)
    with clock() as t:
        nbe, nbon = numpy_voltmeter(ts[:nb], frames[:nb], PRESETS["dvs346"], seed=1)
    wall_b, cpu_b = t.wall_s, t.cpu_s
    pf_b = (nb - 1) * H * W
    m_ours = VoltmeterModel((H, W), preset="dvs346", seed=1)
    ours_nb = m_ours.simulate(ts[:nb], frames[:nb])
    rows.append({"impl": "numpy baseline", "model": "voltmeter", "preset": "dvs346", "frames": nb,
                 "wall_s": wall_b, "cpu_s": cpu_b, "threads": 1, "events": nbe,
                 "on_fraction": nbon / max(nbe, 1), "mpf_per_s": pf_b / wall_b / 1e6,
                 "mpf_per_s_cpu_x_threads": pf_b / cpu_b / 1e6, "mev_per_s": nbe / wall_b / 1e6,
                 "eff_threshold_rel": effective_threshold(PRESETS["dvs346"], 1.0, 0.5)})
    whole = whole_commands(ts, frames, args.voltmeter_repo)
    # memory at two lengths
    lens = (120, 480) if args.quick else (480, 1920)
    mem = [measure_memory(n) for n in lens]
    load1 = os.getloadavg()[0]

    import pandas as pd
    df = pd.DataFrame(rows)
    files = [write_csv("bench_events", df), write_csv("bench_events_memory", pd.DataFrame(mem))]
    with pd.option_context("display.width", 200, "display.max_columns", 20,
                           "display.float_format", "{:.3f}".format):
        print(f"standard sequence: {len(ts)} frames {W}x{H} @2400 fps "
              f"(generated in {t_gen:.2f} s), {pf / 1e6:.1f} M pixel-frames, "
              f"numba threads {threads}, load avg {load0:.1f} -> {load1:.1f} "
              f"(machine shared: 'cpu_x_threads' = pixel-frames per CPU-second x threads)")
        print(df.to_string(index=False))
    ours_b = rows[0]
    one = rows[-2]
    print(f"1 thread: {one['mpf_per_s_cpu_x_threads']:.1f} M pixel-frames per CPU-second -> "
          f"{2 * one['mpf_per_s_cpu_x_threads']:.1f} projected on 2 free cores (target {TARGET_MPF})")
    print(f"baseline check on {nb} frames: numpy {nbe} events (ON {nbon / max(nbe, 1):.3f}) vs "
          f"gs2e {len(ours_nb)} (ON {ours_nb.p.mean():.3f})")
    speed_vs_numpy = ours_b["mpf_per_s"] / rows[-1]["mpf_per_s"]
    print(f"per core (CPU time, 1 thread each): gs2e {one['mpf_per_s_cpu_x_threads']:.1f} vs numpy "
          f"{rows[-1]['mpf_per_s_cpu_x_threads']:.1f} M pixel-frames/s = "
          f"{one['mpf_per_s_cpu_x_threads'] / rows[-1]['mpf_per_s_cpu_x_threads']:.1f}x")
    print(f"speed-up vs numpy baseline (wall): {speed_vs_numpy:.1f}x; "
          f"vs public DVS-Voltmeter figure {PUBLIC_MPF} Mpf/s: "
          f"{ours_b['mpf_per_s'] / PUBLIC_MPF:.1f}x wall, "
          f"{ours_b['mpf_per_s_cpu_x_threads'] / PUBLIC_MPF:.1f}x per-CPU")
    for m in mem:
        print(f"streaming pipeline (model + HDF5 + stats), {m['n_frames']} frames: "
              f"peak RSS {m['peak_rss_mb']:.0f} MB, {m['n_events']} events")

    g = whole["gs2e"]
    print(f"whole command on {len(ts)} PNG frames: gs2e events {g['wall_s']:.2f} s wall, best of "
          f"3 fresh processes (median {g['wall_median_s']:.2f} s) "
          f"({g['events']} events, ON {g['on_fraction']:.3f}; inside: frames {g['source_s']:.2f} s, "
          f"model {g['model_s']:.2f} s, statistics {g['stats_s']:.2f} s, HDF5 {g['write_s']:.2f} s, "
          f"closing {g['close_s']:.2f} s)")
    if "official" in whole:
        o = whole["official"]
        print(f"official DVS-Voltmeter main.py: {o['wall_s']:.2f} s wall ({o['events']} events, "
              f"ON {o['on_fraction']:.3f}) -> gs2e is {o['wall_s'] / g['wall_s']:.1f}x faster "
              f"(target >= 15x)")
        whole_head = (f"whole command {o['wall_s'] / g['wall_s']:.1f}x faster than the official "
                      f"DVS-Voltmeter ({g['wall_s']:.2f} vs {o['wall_s']:.2f} s, {g['events'] / 1e6:.2f} vs "
                      f"{o['events'] / 1e6:.2f} M events)")
    else:
        whole_head = ("official DVS-Voltmeter not measured ("
                      f"{whole.get('official_error', 'no checkout at --voltmeter-repo')})")
        print(whole_head)
    files.append(write_csv("bench_events_whole", pd.DataFrame(
        [{"impl": k, **v} for k, v in whole.items() if isinstance(v, dict)])))

    plt = pyplot()
    fig, ax = plt.subplots(1, 2, figsize=(11, 4))
    lab = [f"{r['impl']}\n{r['model']} {r['preset']}" for r in rows]
    ax[0].barh(lab, df["mpf_per_s"], label="wall")
    ax[0].barh(lab, df["mpf_per_s_cpu_x_threads"], alpha=0.4, label="per CPU-s x threads")
    ax[0].axvline(TARGET_MPF, color="r", ls="--", label="target 65")
    ax[0].axvline(PUBLIC_MPF, color="k", ls=":", label="public code 4.3")
    ax[0].set_xlabel("M pixel-frames / s")
    ax[0].legend(fontsize=7)
    ax[1].plot([m["n_frames"] for m in mem], [m["peak_rss_mb"] for m in mem], "o-")
    ax[1].set_xlabel("frames")
    ax[1].set_ylabel("peak RSS (MB)")
    ax[1].set_ylim(0, None)
    ax[1].set_title("streaming pipeline memory")
    files.append(save_plot(fig, "bench_events", dpi=100))
    report(None, f"HEADLINE: {whole_head}; voltmeter dvs346 {ours_b['mpf_per_s']:.1f} M pixel-frames/s wall "
                 f"on {threads} threads, shared machine (1-thread CPU-time: "
                 f"{one['mpf_per_s_cpu_x_threads']:.1f}/core, x2 = "
                 f"{2 * one['mpf_per_s_cpu_x_threads']:.1f}), "
                 f"{ours_b['mev_per_s']:.1f} M events/s; {speed_vs_numpy:.0f}x numpy baseline, "
                 f"{ours_b['mpf_per_s'] / PUBLIC_MPF:.1f}x public DVS-Voltmeter (4.3); peak RSS "
                 f"{mem[0]['peak_rss_mb']:.0f} MB @{mem[0]['n_frames']} vs {mem[1]['peak_rss_mb']:.0f} MB "
                 f"@{mem[1]['n_frames']} frames", files)


if __name__ == "__main__":
    main()
