"""Benchmark: is a pixel's log luminance smooth in time between renders? (issue 45)

bench_event_between.py finds that a curve with exact time derivatives
predicts log luminance between renders only a little better than a line, at
the steps fixed 2400 fps takes. This asks why, by rendering the same model
with and without the rasteriser's discontinuities. On a crop of each scene
(``--crop`` px square where the view at the span's middle has the most
texture: the largest summed |gradient| of log L, so that a scene off the
image's centre is measured; the event stage's DAVIS346 camera), log luminance log(L + eps) is rendered by a dense float64 torch
compositor (the projection, colours and window of :mod:`gs2e.splat.reference`)
in three variants:

* ``rasteriser``: the rasteriser's window, as gs2e renders: alpha cut at 3
  sigma (power below -4.5) and below 1/255, compositing stopped where
  transmittance falls below 1e-4, the depth order sorted at every render. A
  Gaussian whose edge crosses a pixel changes it by a jump of up to 1.1 % of
  its opacity, and two Gaussians that swap depth order change it by a jump;
* ``smooth_window``: alpha tapered to 0 at 3 sigma, o (e^power - e^-4.5) /
  (1 - e^-4.5) (continuous), no 1/255 cut, no early stop; still sorted at every
  render, so depth-order swaps remain;
* ``smooth_fixed_order``: the same with the depth order of the step's middle
  for every render of the step (truth included): no jump at all;
* ``gs2e_smooth``: gs2e's own renderer (float64) with ``splat.window:
  smooth`` (alpha less its tangent at the cut: C1; weights faded before a
  pixel stops), sorted at every render;
* ``gs2e_continuous``: the same through gs2e's continuous renderer
  (:class:`gs2e.splat.forward.ContinuousRenderer`: depth orders held at knots
  2 px of motion apart, ``render.order_step_px``, and cross-faded), what the
  event stage renders for a model trained with the smooth window. Its order
  does not depend on the step measured, unlike ``smooth_fixed_order``'s.

The gs2e variants render the whole DAVIS346 image (then cropped), of the
model trained with the smooth window by ``bench_window.py`` where it has
cached one (else of the cut model: the window, not the weights, decides
smoothness; the row's ``gs2e_model`` says which).

Per variant and step (px of image motion, :func:`gs2e.splat.forward.image_motion_px`,
the ``motion`` clock's unit): the mean |error| of linear interpolation (what the
event models assume) and of the cubic Hermite curve with exact slopes
(``event_runs.exact_slope``) at 1/4, 1/2 and 3/4 of the step, against renders
there; and the log-log slope of the error against the step: 2 for a signal
smooth in time (a line's error is its curvature times h^2), about 1 or less
where it jumps (the share of steps holding a jump grows with h). The check row
``rasteriser`` against gs2e's own float64 renderer of the whole image (max
|difference| of log L on the crop) shows that the first variant is what gs2e
renders.

Scenes: ``demo``, ``temple_ring``, ``llff_fern`` and ``mouse_colmap`` as built
(cached) by bench_event_sampling.py. ``--quick``: the demo at ``mild``, a 24 px
crop, 2 trials.

Usage: python benchmarks/bench_event_smoothness.py [--quick] [--scenes demo,temple_ring]
       [--speeds mild,strong] [--crop 32] [--steps 0.125,0.25,0.5,1,2] [--trials 4]
Writes benchmarks/results/bench_event_smoothness[_quick].csv and .png; the last
line printed is the headline.
"""

from __future__ import annotations

import numpy as np

import harness
from event_runs import PAPER_FPS, build_scenes, events_cfg, exact_slope, hermite, motion_rate_px_per_us

VARIANTS = ("rasteriser", "smooth_window", "smooth_fixed_order", "gs2e_smooth", "gs2e_continuous")
FRACTIONS = (0.25, 0.5, 0.75)


class CropRenderer:
    """log(L + eps) of a ``size`` x ``size`` crop of ``src``'s (a
    ``RenderedSource``) view with its top left corner at ``origin`` (x0, y0;
    default: centred), dense float64 torch, in one of :data:`VARIANTS`; only
    the Gaussians that reach the crop within ``reach_px`` of image motion of
    ``t_us`` are kept."""

    def __init__(self, src, size: int, t_us: float, rate_px_per_us: float, reach_px: float = 20.0,
                 origin: tuple[int, int] | None = None):
        import torch

        from gs2e.splat.reference import project_reference

        self.torch = torch
        self.src, self.size = src, int(size)
        K, (H, W) = src.K, src.shape
        self.x0, self.y0 = origin if origin is not None else (W // 2 - size // 2, H // 2 - size // 2)
        self.K = K
        self.deg = int(src.info["sh_degree"])
        P = {k: torch.as_tensor(np.asarray(v.detach().cpu().numpy() if hasattr(v, "detach") else v),
                                dtype=torch.float64) for k, v in src.params.items()}
        sh = torch.cat([P["sh_dc"], P["sh_rest"]], 1) if "sh_dc" in P else P["sh"]
        n = P["means"].shape[0]
        keep = torch.zeros(n, dtype=torch.bool)
        for t in t_us + np.linspace(-reach_px, reach_px, 9) / rate_px_per_us:
            m2, _, _, r = project_reference(P["means"], P["quats"], P["log_scales"], self.camera(t))
            u, v = m2[:, 0] - self.x0, m2[:, 1] - self.y0
            keep |= (r > 0) & (u + r >= -reach_px) & (u - r <= size + reach_px) & (v + r >= -reach_px) \
                & (v - r <= size + reach_px)
        self.g = {k: v[keep] for k, v in P.items() if v.shape[0] == n}
        self.sh = sh[keep]
        self.n_gaussians = int(keep.sum())
        self.eps = src.log_eps
        self.order = None  # depth order held for smooth_fixed_order

    def camera(self, t_us: float):
        """The whole view's camera (its projection clamps depend on the image size)."""
        from gs2e.splat.rasterize import SplatCamera

        K, (H, W) = self.K, self.src.shape
        return SplatCamera.from_c2w(self.src.traj.pose_at(np.array([t_us]))[0], K[0, 0], K[1, 1],
                                    K[0, 2], K[1, 2], W, H)

    def hold_order(self, t_us: float | None) -> None:
        """Hold the depth order at ``t_us`` for smooth_fixed_order (None: release)."""
        from gs2e.splat.reference import project_reference

        if t_us is None:
            self.order = None
            return
        z = project_reference(self.g["means"], self.g["quats"], self.g["log_scales"], self.camera(t_us))[2]
        self.order = self.torch.sort(z, stable=True).indices

    def log_luminance(self, t_us: float, variant: str) -> np.ndarray:
        from gs2e.events.sampling import image_luminance
        from gs2e.splat import raster
        from gs2e.splat.reference import project_reference, reference_alpha, reference_colors

        torch, g, S = self.torch, self.g, self.size
        cam = self.camera(t_us)
        m2, con, z, radii = project_reference(g["means"], g["quats"], g["log_scales"], cam)
        col = reference_colors(g["means"], self.sh, torch.as_tensor(cam.campos()), self.deg)
        opac = torch.sigmoid(g["opacity_logits"])
        # drawn and reaching the crop (beyond its box a Gaussian adds nothing in any variant)
        u, v = m2[:, 0] - self.x0, m2[:, 1] - self.y0
        vis = (radii > 0) & (u + radii >= 0) & (u - radii <= S) & (v + radii >= 0) & (v - radii <= S)
        if variant == "smooth_fixed_order":
            idx = self.order[vis[self.order]]
        else:
            idx = torch.nonzero(vis).flatten()
            idx = idx[torch.sort(z[idx], stable=True).indices]
        A, B, C = con[idx].unbind(1)
        jj, ii = torch.meshgrid(torch.arange(S, dtype=torch.float64) + self.x0 + 0.5,
                                torch.arange(S, dtype=torch.float64) + self.y0 + 0.5, indexing="xy")
        dx = m2[idx, 0][None] - jj.reshape(-1, 1)
        dy = m2[idx, 1][None] - ii.reshape(-1, 1)
        power = -0.5 * (A * dx * dx + C * dy * dy) - B * dx * dy
        if variant == "rasteriser":
            alpha = reference_alpha(power, opac[idx])
        else:
            e0 = float(np.exp(raster.POWER_MIN))
            taper = torch.clamp(torch.exp(torch.clamp(power, max=0.0)) - e0, min=0.0) / (1.0 - e0)
            alpha = torch.clamp(opac[idx][None] * taper, max=raster.ALPHA_MAX)
        T = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1 - alpha[:, :-1]], 1), 1)
        rgb = ((alpha * T) @ col[idx]).reshape(S, S, 3).numpy()
        lum = np.empty((S, S))
        image_luminance(rgb, lum)
        return np.log(lum + self.eps)


def busiest_crop(log_l: np.ndarray, size: int) -> tuple[int, int]:
    """(x0, y0) of the ``size`` x ``size`` window of the (H, W) image
    ``log_l`` with the largest sum of |d/dx| + |d/dy| (ties: the first in
    row order): where the scene has texture that motion changes."""
    g = np.zeros_like(log_l)
    g[:, :-1] += np.abs(np.diff(log_l, axis=1))
    g[:-1, :] += np.abs(np.diff(log_l, axis=0))
    H, W = g.shape
    if size > min(H, W):
        raise SystemExit(f"--crop {size} is larger than the {W} x {H} view")
    c = np.zeros((H + 1, W + 1))
    c[1:, 1:] = g.cumsum(0).cumsum(1)
    # each window's sum, indexed by its top left corner
    box = c[size:, size:] - c[:-size, size:] - c[size:, :-size] + c[:-size, :-size]
    y0, x0 = np.unravel_index(int(np.argmax(box)), box.shape)
    return int(x0), int(y0)


def case(model_dir, traj_path, sensor: str, crop: int, steps_px, trials: int,
         smooth_model_dir=None) -> list[dict]:
    """Rows (variant, step) of one scene and trajectory, and the check row."""
    from gs2e.events.rendered import RenderedSource
    from gs2e.events.sampling import image_luminance
    from gs2e.events.settings import event_settings
    from gs2e.splat.forward import ForwardRenderer

    cfg = event_settings(events_cfg("voltmeter", "fixed", extra={"sensor": sensor}))
    src = RenderedSource(model_dir, traj_path, cfg)
    K, (H, W) = src.K, src.shape
    whole = ForwardRenderer(src.params, int(src.info["sh_degree"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                            W, H, dtype=np.float64)
    t_mid = 0.5 * (src.t0_us + src.t1_us)

    def pose(t):
        return src.traj.pose_at(np.array([t]))[0]

    rate = motion_rate_px_per_us(src, t_mid)
    lum = np.empty((H, W))
    image_luminance(whole.render(pose(t_mid)), lum)
    cr = CropRenderer(src, crop, t_mid, rate, origin=busiest_crop(np.log(lum + src.log_eps), crop))
    from gs2e.splat.forward import ContinuousRenderer, order_knots

    from gs2e.splat.model import load_model

    sp, sinfo = load_model(smooth_model_dir) if smooth_model_dir else (src.params, src.info)
    smooth = ForwardRenderer(sp, int(sinfo["sh_degree"]), K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                             W, H, dtype=np.float64, window="smooth")
    t_a, t_b = float(src.traj.t_us[0]), float(src.traj.t_us[-1])
    cont = ContinuousRenderer(smooth, pose, order_knots(smooth, pose, t_a, t_b, 2.0), t_b)

    def gs2e_log(img):
        lum = np.empty((H, W))
        image_luminance(img, lum)
        return np.log(lum + src.log_eps)[cr.y0:cr.y0 + crop, cr.x0:cr.x0 + crop]
    mine = np.log(lum + src.log_eps)[cr.y0:cr.y0 + crop, cr.x0:cr.x0 + crop]
    check = float(np.abs(cr.log_luminance(t_mid, "rasteriser") - mine).max())
    base = {"crop_px": crop, "crop_x0": cr.x0, "crop_y0": cr.y0, "gaussians": cr.n_gaussians,
            "gs2e_model": "smooth-trained" if smooth_model_dir else "cut-trained", "px_per_2400fps_step": rate * 1e6 / PAPER_FPS,
            "check_max_abs_vs_gs2e": check}
    rows = []
    for variant in VARIANTS:
        for step_px in steps_px:
            h = step_px / rate
            err = {"linear": [], "hermite_dt": []}
            for k in range(trials):
                t0 = t_mid + (k - trials / 2) * 3.3 * h
                cr.hold_order(t0 + 0.5 * h if variant == "smooth_fixed_order" else None)

                def G(t):
                    if variant == "gs2e_smooth":
                        return gs2e_log(smooth.render(pose(t)))
                    if variant == "gs2e_continuous":
                        return gs2e_log(cont.render(t))
                    return cr.log_luminance(t, variant)

                g0, g1 = G(t0), G(t0 + h)
                d0, d1 = exact_slope(G, t0, g0, h), exact_slope(G, t0 + h, g1, h)
                for s in FRACTIONS:
                    truth = G(t0 + s * h)
                    err["linear"].append(np.abs((1 - s) * g0 + s * g1 - truth).ravel())
                    err["hermite_dt"].append(np.abs(hermite(g0, d0, g1, d1, s) - truth).ravel())
            rows += [{**base, "variant": variant, "method": m, "step_px": step_px, "step_us": h,
                      "mean_abs": float(np.concatenate(e).mean())} for m, e in err.items()]
    return rows


def exponent(d, lo: float, hi: float) -> float:
    """Least-squares log-log slope of mean |error| against the step over [lo, hi] px."""
    d = d[(d.step_px >= lo) & (d.step_px <= hi) & (d.mean_abs > 0)]
    if len(d) < 2:
        return float("nan")
    return float(np.polyfit(np.log(d.step_px), np.log(d.mean_abs), 1)[0])


def summary(df):
    import pandas as pd

    table, slopes = [], {v: [] for v in VARIANTS}
    gains = {v: [] for v in VARIANTS}
    for (scene, speed), d in df.groupby(["scene", "speed"], sort=False):
        for v in VARIANTS:
            dv = d[d.variant == v]
            lin, her = dv[dv.method == "linear"], dv[dv.method == "hermite_dt"]
            e = exponent(lin, 0.0, 1.0)
            at1 = (float(lin[lin.step_px == 1.0].mean_abs.iloc[0] / her[her.step_px == 1.0].mean_abs.iloc[0])
                   if (lin.step_px == 1.0).any() else float("nan"))
            slopes[v].append(e)
            gains[v].append(at1)
            table.append({"scene": scene, "speed": speed, "variant": v,
                          "gaussians": int(dv.gaussians.iloc[0]),
                          **{f"linear {s:g} px": f"{r.mean_abs:.6f}" for s, r in
                             zip(lin.step_px, lin.itertuples())},
                          **{f"hermite {s:g} px": f"{r.mean_abs:.6f}" for s, r in
                             zip(her.step_px, her.itertuples())},
                          "linear's log-log slope (<= 1 px)": f"{e:.2f}",
                          "linear / hermite at 1 px": f"{at1:.1f}",
                          "check vs gs2e": f"{dv.check_max_abs_vs_gs2e.iloc[0]:.1e}"})

    def rng(v):
        v = np.asarray(v, float)
        v = v[np.isfinite(v)]
        return "n/a" if not len(v) else f"{v.min():.2f}" if v.min() == v.max() else f"{v.min():.2f}-{v.max():.2f}"

    head = ("log-log slope of linear interpolation's error (2 = smooth in time), and linear / exact-slope "
            "Hermite error at 1 px: " + "; ".join(f"{v} {rng(slopes[v])}, {rng(gains[v])}x" for v in VARIANTS)
            + f" ({len(df.groupby(['scene', 'speed']))} cases)")
    with pd.option_context("display.width", 250, "display.max_columns", 40):
        return pd.DataFrame(table), head


def plot(df):
    plt = harness.pyplot()
    cases = list(df.groupby(["scene", "speed"], sort=False))
    fig, axes = plt.subplots(1, len(VARIANTS), figsize=(4.0 * len(VARIANTS), 3.8), sharey=True)
    for ax, v in zip(axes, VARIANTS):
        for i, ((scene, speed), d) in enumerate(cases):
            for m, ls in (("linear", "-"), ("hermite_dt", "--")):
                dm = d[(d.variant == v) & (d.method == m)].sort_values("step_px")
                ax.loglog(dm.step_px, np.maximum(dm.mean_abs, 1e-9), ls, marker="o", ms=3, color=f"C{i}",
                          label=f"{scene} {speed} {m}")
        steps = sorted(df.step_px.unique())
        ax.set_xticks(steps, [f"{s:g}" for s in steps])
        ax.minorticks_off()
        ax.set_title(f"{v} (dashed: Hermite, exact slopes)")
        ax.set_xlabel("step between renders (px of motion)")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("mean |error| of log L between renders")
    handles, labels = axes[0].get_legend_handles_labels()
    keep = [i for i, lab in enumerate(labels) if lab.endswith(" linear")]
    fig.legend([handles[i] for i in keep], [labels[i][:-len(" linear")] for i in keep], fontsize=7,
               loc="center right")
    fig.tight_layout(rect=(0, 0, 0.87, 1))
    return fig


def main() -> None:
    import pandas as pd

    ap = harness.parser(__doc__, quick="demo at mild, a 24 px crop, 2 trials (about a minute once the demo "
                                       "model is cached)")
    ap.add_argument("--scenes", default="demo,temple_ring,llff_fern,mouse_colmap")
    ap.add_argument("--speeds", default="mild,strong")
    ap.add_argument("--sensor", default="davis346")
    ap.add_argument("--crop", type=int, default=32, help="side of the square crop (px)")
    ap.add_argument("--steps", default="0.125,0.25,0.5,1,2", help="px of image motion between renders")
    ap.add_argument("--trials", type=int, default=4, help="steps measured per case")
    args = ap.parse_args()
    if args.quick:
        args.scenes, args.speeds, args.crop, args.trials = "demo", "mild", 24, 2
    steps = [float(s) for s in args.steps.split(",")]
    rows = []
    cache = harness.RESULTS / "bench_window_cache"
    smooth_models = {s: cache / s / "smooth" for s in args.scenes.split(",")
                     if (cache / s / "smooth" / "model.json").exists()}
    with harness.clock() as total:
        for scene, d in build_scenes(args.scenes.split(",")).items():
            for speed in args.speeds.split(","):
                with harness.clock() as t:
                    rows += [{"scene": scene, "speed": speed, "sensor": args.sensor, **r}
                             for r in case(d / "splat", d / "trajectories" / f"base_{speed}.npz",
                                           args.sensor, args.crop, steps, args.trials,
                                           smooth_models.get(scene))]
                print(f"{scene} {speed}: {t.wall_s:.0f} s", flush=True)
    df = pd.DataFrame(rows)
    name = "bench_event_smoothness" + ("_quick" if args.quick else "")
    csv = harness.write_csv(name, df.to_dict("records"))
    png = harness.save_plot(plot(df), name, dpi=110)
    print(f"measured in {total.wall_s:.0f} s")
    harness.report(*summary(df), [csv, png])


if __name__ == "__main__":
    main()
