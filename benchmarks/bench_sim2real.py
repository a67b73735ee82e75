"""Benchmark: simulated against real events on the same scene and motion; the DAVIS346 background refit; the cost of the readout model.

Three parts (issue 48), all on real data of ../shared/data (see SOURCES.md):

1. **Sim-to-real on ECD slider_depth** (DAVIS240C on a linear slider over a
   static table-top): the scene rebuilt by gs2e from the recording's own APS
   frames and poses, simulated along the recorded path, compared with the
   real events (``gs2e bench-sim2real``, run by the workflow:
   ``make sim2real`` builds ``--root``). Each variant's distances and floors
   (the distance of the variant to itself at another seed); the fitted
   ``davis240`` preset against the scene default.
2. **DAVIS346 background refit**: background activity and hot pixels in the
   still region of ``events/davis346_street_aps.aedat4`` (APS std < 0.01),
   against the presets simulated on the recording's own still frames over the
   same pixels for 60 s: the refitted ``davis346`` (ideal model: only the
   preset's noise), the v2e defaults it replaced (leak 0.01 Hz, shot noise
   0.001 Hz), and DVS-Voltmeter (whose diffusion fires on a still scene by
   itself).
3. **Readout cost**: ``gs2e events`` on the trained slider_depth model along
   the recorded path (0.3 s, DVS-Voltmeter, fixed 2400 Hz), one child process
   each: this revision with every readout part off against ``--baseline-rev``
   (before the readout existed), alternated in rotated order after a warm-up
   run of each (numba compiles), ``--reps`` runs: the best and the median
   CPU time (the best is the cost without the machine's interference, which
   here moves the median by 15 %), and the median of the stage's own model
   time (``stats.json`` ``model_s``: the pixel model and the readout parts;
   rendering is the rest); then each part
   on (photoreceptor 300 Hz, 1 % hot pixels at 10 Hz, a 1 Mev/s readout).

    make sim2real        # builds results/sim2real_data, then runs this
    python benchmarks/bench_sim2real.py --root results/sim2real_data [--quick]

Writes benchmarks/results/bench_sim2real[_quick].csv and .png; the last line
printed is the headline.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
from pathlib import Path

import numpy as np

from harness import (REPO, SHARED, baseline_checkout, gs2e_env, parser, pyplot, report, run_child,
                     save_plot, write_csv)

OLD_DAVIS346 = {"leak_rate_hz": 0.01, "shot_noise_rate_hz": 0.001, "shot_noise_on_fraction": 0.5}
READOUT_PARTS = {"photoreceptor": {"photoreceptor_cutoff_hz": 300.0},
                 "hot_pixels": {"hot_pixel_fraction": 0.01, "hot_pixel_rate_hz": 10.0},
                 "readout": {"readout_rate_meps": 1.0, "readout_latency_us": 20.0,
                             "readout_jitter_us": 5.0, "readout_queue_events": 256}}


def sim2real_rows(folder: Path) -> list[dict]:
    import pandas as pd

    d = pd.read_parquet(folder / "distances.parquet")
    return [{"part": "sim2real", **r} for r in d.to_dict("records")]


def street_rows(sim_s: float) -> list[dict]:
    """Real still-region background against presets simulated on its frames."""
    from gs2e.events.models import make_model
    from gs2e.events.readout import SensorChain, resolve_readout
    from gs2e.events.recordings import read_aedat4_frames
    from gs2e.events.settings import event_settings
    from gs2e.events.stats import still_background

    rec = read_aedat4_frames(SHARED / "events" / "davis346_street_aps.aedat4")
    real = still_background(rec.events, rec.shape, rec.frames)
    lum = rec.frames.mean(axis=0).astype(np.float32)
    ts = np.arange(0, int(sim_s * 1e6) + 1, 500_000, dtype=np.int64)
    frames = np.broadcast_to(lum, (len(ts), *lum.shape))
    keys = ("ba_rate_hz", "ba_on_fraction", "hot_fraction", "hot_rate_hz")
    rows = [{"part": "street", "variant": "real (still region)", **{k: real[k] for k in keys},
             "still_fraction": real["still_fraction"]}]
    variants = {"davis346 refitted (ideal model)": {"sensor": "davis346", "model": "ideal",
                                                    "theta_on": 0.2, "theta_off": 0.2},
                "davis346 before (v2e defaults, ideal model)": {"sensor": "davis346", "model": "ideal",
                                                                "theta_on": 0.2, "theta_off": 0.2,
                                                                **OLD_DAVIS346},
                "davis346 refitted + DVS-Voltmeter": {"sensor": "davis346", "model": "voltmeter"}}
    for name, s in variants.items():
        model, _ = make_model(event_settings(s), rec.shape, 11)
        ev = SensorChain(model, resolve_readout(event_settings(s))[0], 11).simulate(ts, frames)
        sim = still_background(ev, rec.shape, rec.frames, mask=real["_mask"]) if len(ev) > 1 else None
        row = {"part": "street", "variant": name}
        for k in keys:
            row[k] = sim[k] if sim else 0.0
            if k in ("ba_rate_hz", "hot_rate_hz"):
                row[f"{k}_rel_error"] = (row[k] / real[k] - 1) if real[k] > 0 else (0.0 if row[k] == 0 else math.inf)
        rows.append(row)
    return rows


def readout_rows(root: Path, rev: str, reps: int, span_s: float) -> list[dict]:
    """CPU seconds of `gs2e events` children: baseline, this revision with the
    readout off, and each readout part on."""
    model = root / "slider_depth" / "splat"
    traj = root / "slider_depth" / "sim2real" / "trajectory.npz"
    if not model.is_dir() or not traj.is_file():
        raise SystemExit(f"{model} or {traj} missing: run make sim2real first")
    out = Path("/tmp/gs2e_bench_readout")
    base_cfg = {"max_duration_s": span_s, "preview": False, "num_threads": 1}

    def cmd(root_: Path, extra: dict) -> list[str]:
        return [sys.executable, "-m", "gs2e", "events", "--model", str(model), "--trajectory", str(traj),
                "-o", str(out / "o"), "--threads", "1", "--config-json", json.dumps({**base_cfg, **extra})]

    names = ["baseline", "readout off", *READOUT_PARTS]
    runs: dict[str, list] = {k: [] for k in names}
    chain_s: dict[str, list] = {k: [] for k in names}
    n_events = {}
    with baseline_checkout(rev) as base:
        order = [("baseline", base, {}), ("readout off", REPO, {}),
                 *((k, REPO, v) for k, v in READOUT_PARTS.items())]
        for _, root_, extra in order:
            run_child(cmd(root_, extra), env=gs2e_env(root_))  # warm-up: numba compiles and caches
        for rep in range(reps):  # alternated, each rep in a rotated order: drifts hit all alike
            for name, root_, extra in order[rep % len(order):] + order[:rep % len(order)]:
                r = run_child(cmd(root_, extra), env=gs2e_env(root_))
                if r.returncode != 0:
                    raise SystemExit(f"{name}: gs2e events failed:\n{r.output[-2000:]}")
                runs[name].append(r.cpu_s)
                st = json.loads((out / "o" / "stats.json").read_text())["stats"]
                chain_s[name].append(st["model_s"])  # the model and the readout parts
                n_events[name] = st["n_events"]
    b_med, b_min = statistics.median(runs["baseline"]), min(runs["baseline"])
    b_chain = statistics.median(chain_s["baseline"])
    return [{"part": "readout_cost", "variant": k, "cpu_s_median": statistics.median(runs[k]),
             "cpu_s_min": min(runs[k]), "ratio_median": statistics.median(runs[k]) / b_med,
             "ratio_min": min(runs[k]) / b_min, "model_s_median": statistics.median(chain_s[k]),
             "model_ratio": statistics.median(chain_s[k]) / b_chain, "reps": len(runs[k]),
             "n_events": n_events[k]} for k in names]


def plot(rows: list[dict], name: str) -> Path:
    plt = pyplot()
    s2r = [r for r in rows if r["part"] == "sim2real"]
    metrics = list(dict.fromkeys(r["metric"] for r in s2r))
    variants = list(dict.fromkeys(r["variant"] for r in s2r))
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.2), gridspec_kw={"width_ratios": [2.2, 1]})
    w = 0.8 / max(1, len(variants))
    for i, v in enumerate(variants):
        vals = [next((r["distance"] for r in s2r if r["variant"] == v and r["metric"] == m), np.nan)
                for m in metrics]
        floors = [next((r["floor"] for r in s2r if r["variant"] == v and r["metric"] == m), np.nan)
                  for m in metrics]
        x = np.arange(len(metrics)) + i * w
        axes[0].bar(x, vals, w, label=v)
        axes[0].scatter(x, floors, marker="_", color="k", s=60, zorder=3)
    axes[0].set_xticks(np.arange(len(metrics)) + 0.4 - w / 2, metrics, rotation=30, ha="right", fontsize=8)
    axes[0].set_ylabel("distance to the real events (black: floor)")
    axes[0].set_title("slider_depth: simulated vs real")
    axes[0].legend(fontsize=7)
    st = [r for r in rows if r["part"] == "street"]
    axes[1].barh([r["variant"] for r in st], [r["ba_rate_hz"] for r in st])
    axes[1].set_xscale("log")
    axes[1].set_xlabel("background rate in the still region (Hz per pixel)")
    axes[1].tick_params(axis="y", labelsize=7)
    axes[1].set_title("DAVIS346 street")
    return save_plot(fig, name)


def main() -> None:
    ap = parser(__doc__, quick="parts 1 and 2, and part 3 with one repetition of 0.1 s (about 2 min); "
                               "without --root's data, part 2 alone (20 s simulated, about 20 s)",
                baseline_rev="268273e")
    ap.add_argument("--reps", type=int, default=5, help="repetitions of part 3 (alternated; median)")
    ap.add_argument("--root", default=str(REPO / "results" / "sim2real_data"),
                    help="results folder of make sim2real (slider_depth/sim2real, slider_depth/splat)")
    args = ap.parse_args()
    import pandas as pd

    root = Path(args.root)
    folder = root / "slider_depth" / "sim2real"
    if not (folder / "distances.parquet").is_file():
        if not args.quick:
            raise SystemExit(f"{folder}/distances.parquet missing: run make sim2real first")
        # make bench: the part that needs no workflow run
        rows = street_rows(20.0)
        name = "bench_sim2real_quick"
        st = [r for r in rows if r["variant"] == "davis346 refitted (ideal model)"][0]
        report(pd.DataFrame(rows).drop(columns="part"),
               f"headline (quick, parts 1 and 3 not run: no {folder}): street background, refitted "
               f"davis346 {st['ba_rate_hz_rel_error']:+.0%} of the real",
               [write_csv(name, rows)])
        return
    rows = sim2real_rows(folder)
    rows += street_rows(60.0)
    rows += readout_rows(root, args.baseline_rev, 1 if args.quick else args.reps, 0.1 if args.quick else 0.3)
    name = "bench_sim2real_quick" if args.quick else "bench_sim2real"
    df = pd.DataFrame(rows)
    files = [write_csv(name, df), plot(rows, name)]

    s2r = df[df["part"] == "sim2real"]
    piv = s2r.pivot(index="metric", columns="variant", values="distance")
    floor = s2r.pivot(index="metric", columns="variant", values="floor")
    print("sim-to-real distances (floor in brackets):")
    print(piv.round(3).astype(str).add(" (").add(floor.round(3).astype(str)).add(")").to_string())
    closer = [m for m in piv.index if piv.at[m, "davis240"] < piv.at[m, "scene"]]
    print(f"davis240 closer than the scene default on {len(closer)}/{len(piv)}: {', '.join(closer)}")
    st = df[df["part"] == "street"][["variant", "ba_rate_hz", "ba_rate_hz_rel_error", "ba_on_fraction",
                                     "hot_fraction", "hot_rate_hz"]]
    print(st.to_string(index=False))
    rc = df[df["part"] == "readout_cost"][["variant", "cpu_s_median", "cpu_s_min", "ratio_median", "ratio_min",
                                           "model_s_median", "model_ratio", "reps", "n_events"]]
    fit = json.loads((folder / "fit.json").read_text())
    refit = st[st["variant"] == "davis346 refitted (ideal model)"].iloc[0]
    off = rc[rc["variant"] == "readout off"].iloc[0]
    tot = piv.sum()
    report(rc.round(3), f"headline: slider_depth sum of distances: scene default {tot['scene']:.2f}, "
                        f"davis240 {tot['davis240']:.2f} (closer on {len(closer)}/{len(piv)}), fits "
                        + ", ".join(f"{m} {tot[f'fitted_{m}']:.2f}" for m in fit["fits"])
                        + f"; street background: refitted davis346 {refit['ba_rate_hz_rel_error']:+.0%} "
                          f"of the real; readout off / baseline CPU {off['ratio_min']:.3f} (best of "
                          f"{int(off['reps'])}; median {off['ratio_median']:.3f}), model + readout "
                          f"time {off['model_ratio']:.3f}", files)


if __name__ == "__main__":
    main()
