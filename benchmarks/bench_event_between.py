"""Benchmark: how well log luminance between two renders is predicted from them (issue 45).

The event models take log luminance G = log(L + eps) as linear in time between
two samples. A sampler could render less often and predict the values between
renders, if a prediction were accurate enough at a step long enough to pay for
what it costs. This measures the error of three predictions against whole
renders at the times between, per step between renders (in px of image motion,
:func:`gs2e.splat.forward.image_motion_px`, the unit of the ``motion`` clock):

* ``linear``: (1 - s) G0 + s G1, what the event models assume (one render per step);
* ``hermite_nb``: a cubic Hermite curve with slopes from the neighbouring
  renders, (G(t + h) - G(t - h)) / 2 per step h (one render per step; tried
  for issue 45 and dropped, docs/events.md);
* ``hermite_dt``: a cubic Hermite curve with the render's own time derivative
  at each end, as forward-mode differentiation through the rasteriser along the
  camera's velocity would give it. It is taken here from one-sided differences
  over +-2 us in float64, of the two the smaller in magnitude (where a
  Gaussian crosses the opacity cut-off within 2 us, the derivative almost
  everywhere, not the jump). Its error is an estimate of what exact slopes
  would give; its cost would be a render and a tangent pass per step.

At fractions s = 1/4, 1/2, 3/4 of steps from the middle of ``base_<speed>``,
on the event stage's own luminance (the sensor's camera, sRGB decoded, Rec.
709; rendered in float64). Per method and step: the share of pixels off by
more than 0.05 in G (the threshold of the issue's by-hand test; a quarter of
DVS-Voltmeter's smallest theta), the mean and the 99th percentile of |error|.
The headline: how much longer a step the exact slopes allow at the error of
linear interpolation at 1 px, which a tangent pass must cost less than (in
renders) to pay.

Scenes: ``demo``, ``temple_ring``, ``llff_fern`` and ``mouse_colmap`` as built
(cached) by bench_event_sampling.py. ``--quick``: the demo at ``mild``, steps of 1 and 2 px.

Usage: python benchmarks/bench_event_between.py [--quick] [--scenes demo,temple_ring]
       [--speeds mild,strong] [--sensor davis346] [--steps 0.25,0.5,1,2,4] [--trials 4]
Writes benchmarks/results/bench_event_between[_quick].csv and .png; the last
line printed is the headline.
"""

from __future__ import annotations

import numpy as np

import harness
from event_runs import build_scenes, events_cfg

FRACTIONS = (0.25, 0.5, 0.75)
SLOPE_DT_US = 2.0
OFF_LOG = 0.05
METHODS = ("linear", "hermite_nb", "hermite_dt")


def hermite(g0, d0, g1, d1, s):
    """Cubic Hermite curve through g0, g1 with slopes d0, d1 (per step) at s in [0, 1]."""
    s2, s3 = s * s, s * s * s
    return ((2 * s3 - 3 * s2 + 1) * g0 + (s3 - 2 * s2 + s) * d0 + (3 * s2 - 2 * s3) * g1
            + (s3 - s2) * d1)


def case(model_dir, traj_path, sensor: str, steps_px, trials: int) -> list[dict]:
    """Rows (method, step) of one scene and trajectory."""
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.sampling import image_luminance
    from gs2e.splat.forward import ForwardRenderer, image_motion_px

    src = RenderedSource(model_dir, traj_path, events_cfg("voltmeter", "fixed", extra={"sensor": sensor}))
    eps = src.log_eps
    K, (H, W) = src.K, src.shape
    fr = ForwardRenderer(src.params, int(src.info["sh_degree"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                         W, H, dtype=np.float64)
    lum = np.empty((H, W), np.float64)

    def G(t_us: float) -> np.ndarray:
        image_luminance(fr.render(src.traj.pose_at(np.array([t_us]))[0]), lum)
        return np.log(lum + eps)

    t_mid = 0.5 * (src.t0_us + src.t1_us)
    rate = image_motion_px(fr.centres(src.traj.pose_at(np.array([t_mid]))[0]),
                           fr.centres(src.traj.pose_at(np.array([t_mid + 200.0]))[0])) / 200.0
    rows = []
    for step_px in steps_px:
        h = step_px / rate
        err = {m: [] for m in METHODS}
        for k in range(trials):
            t0 = t_mid + (k - trials / 2) * 3.3 * h
            t1 = t0 + h
            g0, g1 = G(t0), G(t1)
            nb0 = 0.5 * (g1 - G(t0 - h))
            nb1 = 0.5 * (G(t1 + h) - g0)
            dt = []
            for t, g in ((t0, g0), (t1, g1)):
                fwd, bwd = G(t + SLOPE_DT_US) - g, g - G(t - SLOPE_DT_US)
                dt.append(np.where(np.abs(fwd) < np.abs(bwd), fwd, bwd) * (h / SLOPE_DT_US))
            for s in FRACTIONS:
                truth = G(t0 + s * h)
                err["linear"].append(np.abs((1 - s) * g0 + s * g1 - truth).ravel())
                err["hermite_nb"].append(np.abs(hermite(g0, nb0, g1, nb1, s) - truth).ravel())
                err["hermite_dt"].append(np.abs(hermite(g0, dt[0], g1, dt[1], s) - truth).ravel())
        for m, e in err.items():
            e = np.concatenate(e)
            rows.append({"method": m, "step_px": step_px, "step_us": h, "width": W, "height": H,
                         "off_share": float((e > OFF_LOG).mean()), "mean_abs": float(e.mean()),
                         "p99_abs": float(np.percentile(e, 99))})
    return rows


def step_at(df, method: str, value: float) -> float:
    """Step (px) at which ``method``'s mean error reaches ``value``: log-log
    interpolation on the first measured segment that brackets it; inf if the
    error stays below it up to the longest step measured, nan if it is
    already above it at the shortest."""
    d = df[df.method == method].sort_values("step_px")
    x, y = np.log(d.step_px.to_numpy()), np.log(d.mean_abs.to_numpy())
    v = np.log(value)
    if y[0] > v:
        return float("nan")
    for i in range(len(y) - 1):
        if y[i] <= v <= y[i + 1]:
            return float(np.exp(x[i] + (v - y[i]) / (y[i + 1] - y[i]) * (x[i + 1] - x[i]))
                         if y[i + 1] > y[i] else np.exp(x[i]))
    return float("inf")


def summary(df):
    """One row per case and step (the three methods side by side), and the headline."""
    import pandas as pd

    table, gains = [], []
    for (scene, speed), d in df.groupby(["scene", "speed"], sort=False):
        lin1 = d[(d.method == "linear") & (d.step_px == 1.0)]
        gain = step_at(d, "hermite_dt", float(lin1.mean_abs.iloc[0])) if len(lin1) else float("nan")
        gains.append(gain)
        for step, ds in d.groupby("step_px"):
            r = {m: ds[ds.method == m].iloc[0] for m in METHODS}
            table.append({"scene": scene, "speed": speed, "step px": f"{step:g}",
                          "step us": f"{r['linear'].step_us:.0f}",
                          **{f"mean |err| {m}": f"{r[m].mean_abs:.4f}" for m in METHODS},
                          **{f"> 0.05 {m}": f"{100 * r[m].off_share:.2f} %" for m in METHODS},
                          "hermite_dt step at linear's 1 px error": (
                              f"{gain:.2f} px" if np.isfinite(gain)
                              else f"> {d.step_px.max():g} px" if gain > 0 else "n/a")})
    g = np.array(gains)
    g = g[~np.isnan(g)]  # inf (beyond the longest step measured) stays: it is the best case
    longest = df.step_px.max()

    def px(v):
        return f"{v:.2f}" if np.isfinite(v) else f"more than {longest:g}"

    span = (px(g.min()) if g.min() == g.max() or not np.isfinite(g.min())
            else f"{px(g.min())}-{px(g.max())}") if len(g) else ""
    pay = (f"they pay only if a render with its tangent pass costs less than {span} renders"
           if len(g) and np.isfinite(g.min()) else "longer steps are needed to tell what they pay")
    head = (f"exact time derivatives allow {span} px steps at the mean error of linear "
            f"interpolation at 1 px ({len(g)} cases): {pay}" if len(g)
            else "no case measured linear interpolation at 1 px and exact slopes beyond it")
    return pd.DataFrame(table), head


def plot(df):
    plt = harness.pyplot()
    cases = list(df.groupby(["scene", "speed"], sort=False))
    cols = min(4, len(cases))
    rows = (len(cases) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.2 * rows), squeeze=False)
    steps = sorted(df.step_px.unique())
    for ax, ((scene, speed), d) in zip(axes.flat, cases):
        for m in METHODS:
            dm = d[d.method == m].sort_values("step_px")
            ax.loglog(dm.step_px, dm.mean_abs, "o-", label=m)
        ax.set_title(f"{scene} {speed}")
        ax.set_xticks(steps, [f"{s:g}" for s in steps])
        ax.minorticks_off()
        ax.grid(True, alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("step between renders (px of motion)")
    for ax in axes[:, 0]:
        ax.set_ylabel("mean |error| of log L")
    for ax in list(axes.flat)[len(cases):]:
        ax.axis("off")
    axes[0][0].legend()
    fig.tight_layout()
    return fig


def main() -> None:
    import pandas as pd

    ap = harness.parser(__doc__, quick="demo at mild, steps 1 and 2 px, 2 trials (about 10 s once the demo model is cached)")
    ap.add_argument("--scenes", default="demo,temple_ring,llff_fern,mouse_colmap")
    ap.add_argument("--speeds", default="mild,strong")
    ap.add_argument("--sensor", default="davis346")
    ap.add_argument("--steps", default="0.25,0.5,1,2,4", help="px of image motion between renders")
    ap.add_argument("--trials", type=int, default=4, help="steps measured per case")
    args = ap.parse_args()
    if args.quick:
        args.scenes, args.speeds, args.steps, args.trials = "demo", "mild", "1,2", 2
    steps = [float(s) for s in args.steps.split(",")]
    rows = []
    with harness.clock() as total:
        for scene, d in build_scenes(args.scenes.split(",")).items():
            for speed in args.speeds.split(","):
                for r in case(d / "splat", d / "trajectories" / f"base_{speed}.npz", args.sensor,
                              steps, args.trials):
                    rows.append({"scene": scene, "speed": speed, "sensor": args.sensor, **r})
                print(f"{scene} {speed}: done", flush=True)
    df = pd.DataFrame(rows)
    name = "bench_event_between" + ("_quick" if args.quick else "")
    csv = harness.write_csv(name, df.to_dict("records"))
    png = harness.save_plot(plot(df), name, dpi=110)
    print(f"measured in {total.wall_s:.0f} s")
    harness.report(*summary(df), [csv, png])


if __name__ == "__main__":
    main()
