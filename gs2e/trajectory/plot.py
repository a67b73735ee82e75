"""Per-scene plot: paths over the input cameras coloured by speed, and the
achieved speed profile of the base path against the requested one."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from gs2e.trajectory.curve import pose_deltas


def _plane(points: np.ndarray) -> np.ndarray:
    """(3, 2) projection onto the two principal axes of ``points``."""
    c = points - points.mean(0)
    if len(points) < 3 or not np.any(c):
        return np.eye(3)[:, :2]
    _, _, vt = np.linalg.svd(c, full_matrices=False)
    return vt[:2].T


def preset_lines(trajs: dict) -> list[str]:
    """One line per speed preset of the base path: its duration and what sets it."""
    out = []
    for name, tr in trajs.items():
        if not name.startswith("base_"):
            continue
        dur = (tr.t_us[-1] - tr.t_us[0]) * 1e-6
        step = tr.meta.get("image_step_width_median")
        v = tr.meta.get("preset_values", {})
        if step is not None and v.get("image_speed_width_s") and dur > 0:
            speed = step * (len(tr.t_us) - 1) / dur
            how = f"typical point {speed:.2f} image widths/s ({speed * 2:.1f} % of the width per 20 ms)"
        else:
            how = (f"peak {v.get('max_angular_speed_deg_s')} deg/s or "
                   f"{v.get('max_linear_speed_scale_s')} scales/s (no sparse points)")
        legs = tr.meta.get("legs")
        out.append(f"{name}: {dur:.2f} s, {how}" + (f", back and forth over {legs:.1f} legs" if legs else ""))
    return out


def plot_scene(result, path: str | Path) -> None:
    """Write the scene plot (PNG) to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import LineCollection

    trajs = result.trajectories
    base_name = next((n for n in trajs if n.startswith("base_")), None)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(12, 5.2))
    C_in = result.input_c2w[:, :3, 3]
    proj = _plane(np.concatenate([C_in, result.base.c2w[:, :3, 3]]))
    mu = C_in.mean(0)
    p_in = (C_in - mu) @ proj
    ax0.plot(p_in[:, 0], p_in[:, 1], "k.", ms=7, label="input cameras", zorder=3)
    lcs = []
    speeds_all = []
    for name, tr in trajs.items():
        if name.startswith("base_") and name != base_name:
            continue  # presets share the base path
        P = (tr.c2w[:, :3, 3] - mu) @ proj
        dt_s = np.diff(tr.t_us) * 1e-6
        d = pose_deltas(tr.c2w, tr.meta["alpha"], tr.meta["beta"] / tr.meta["translation_scale"])
        speed = d / np.maximum(dt_s, 1e-12)
        seg = np.stack([P[:-1], P[1:]], axis=1)
        lcs.append((seg, speed, name))
        speeds_all.append(speed)
    if speeds_all:
        allv = np.concatenate(speeds_all)
        norm = plt.Normalize(float(allv.min()), float(allv.max()) + 1e-12)
        for seg, speed, name in lcs:
            lc = LineCollection(seg, cmap="viridis", norm=norm,
                                linewidths=2.5 if name == base_name else 1.2)
            lc.set_array(speed)
            ax0.add_collection(lc)
            ax0.annotate(name, seg[0, 0], fontsize=7, annotation_clip=True)
        fig.colorbar(lc, ax=ax0, label="metric speed per second (alpha*rad + beta*scale)")
    ax0.autoscale()
    ax0.margins(0.12)  # room for the path labels at the edges
    ax0.set_aspect("equal", adjustable="datalim")
    ax0.set_title("camera paths written (principal plane of the camera centres);\n"
                  "render.trajectories picks the ones rendered", fontsize=9)
    ax0.set_xlabel("first principal axis (scene units)")
    ax0.set_ylabel("second principal axis (scene units)")
    ax0.legend(loc="best", fontsize=8)
    if base_name:
        from gs2e.trajectory.trajectory import achieved_steps_fine
        tr = trajs[base_name]
        n = len(result.base.s)  # one leg of a back-and-forth path
        beta_n = tr.meta["beta"] / tr.meta["translation_scale"]
        t = np.linspace(0.0, 1.0, n)[:-1]
        ds = np.diff(tr.s[:n])  # proportional to the requested v(t_j) by construction
        req = ds / ds.mean()
        fine = achieved_steps_fine(result.base, tr.meta["alpha"], beta_n)
        chord = pose_deltas(tr.c2w[:n], tr.meta["alpha"], beta_n)
        ax1.plot(t, req, "-", lw=3, color="0.75", label="requested v(t) (relative)")
        ax1.plot(t, fine / fine.mean(), "--", lw=1.3, color="C3",
                 label="achieved: arc length travelled per step")
        ax1.plot(t, chord / fine.mean(), ":", lw=1.0, color="C0",
                 label="frame-to-frame chord (shorter where the path turns)")
        ax1.set_xlabel("normalised time t")
        ax1.set_ylabel("relative speed")
        err = tr.meta.get("max_rel_step_error", float("nan"))
        ax1.set_title(f"base path speed profile (max rel. step error {err:.1e})")
        ax1.legend(fontsize=8)
        # below the axes, not over the curves
        ax1.text(0.0, -0.16, "\n".join(preset_lines(trajs)), transform=ax1.transAxes, fontsize=7,
                 va="top", family="monospace", bbox={"fc": "white", "ec": "0.8"})
    fig.tight_layout()
    fig.savefig(path, dpi=90, bbox_inches="tight")  # the preset box sits below the axes
    plt.close(fig)
