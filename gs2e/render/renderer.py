"""Rendering a trained Gaussian model along a timed trajectory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from gs2e.common.camera import render_camera
from gs2e.common.color import luminance, srgb_to_linear
from gs2e.common.errors import InputError
from gs2e.splat.backend import resolve_backend_for
from gs2e.splat.rasterize import SplatCamera
from gs2e.splat.model import load_model, model_window, render
from gs2e.trajectory import load_trajectory


class TrajectoryRenderer:
    """Renders the model in ``model_dir`` at any time of the trajectory file.

    Images are (H, W, 3) float64 sRGB-encoded in [0, 1] (what 3DGS reproduces),
    alpha (H, W) and expected depth (H, W, scene units, camera z).
    """

    def __init__(self, model_dir: str | Path, trajectory_path: str | Path, background=(0.0, 0.0, 0.0),
                 scale: float = 1.0, backend: str = "cpu",
                 sensor: tuple[tuple[int, int], str] | None = None, order_step_px: float = 2.0):
        self.params, self.info = load_model(model_dir)
        self.window = model_window(self.info)
        self.backend = resolve_backend_for(backend, self.window, "render.backend")
        self.order_step_px = float(order_step_px)
        self._continuous = None  # built on the first rgb_at of a smooth-window model
        self.traj = load_trajectory(trajectory_path)
        self.name = Path(trajectory_path).stem
        # the event sensor's camera ((W, H), fit) when given; then scale does not apply
        self.K, self.width, self.height = render_camera(self.traj.K, self.traj.width,
                                                        self.traj.height, scale, sensor)
        self.fx, self.fy, self.cx, self.cy = (self.K[0, 0], self.K[1, 1], self.K[0, 2],
                                              self.K[1, 2])
        self.bg = torch.tensor(background, dtype=self.params["means"].dtype)
        self.sh_degree = int(self.info["sh_degree"])
        self.t0_us, self.t1_us = int(self.traj.t_us[0]), int(self.traj.t_us[-1])
        self.renders = 0
        self._forward = None  # built on the first render_rgb

    def pose(self, t_us: float) -> np.ndarray:
        if not self.t0_us <= t_us <= self.t1_us:
            raise InputError(f"trajectory {self.name}: time {t_us} us outside [{self.t0_us}, {self.t1_us}]")
        return self.traj.pose_at(np.array([float(t_us)]))[0]

    def render_pose(self, c2w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        cam = SplatCamera.from_c2w(c2w, self.fx, self.fy, self.cx, self.cy, self.width, self.height)
        with torch.no_grad():
            img, alpha, depth, _ = render(self.params, cam, self.bg, self.sh_degree, self.backend,
                                          window=self.window)
        self.renders += 1
        return (img.clamp(0, 1).double().numpy(), alpha.double().numpy(), depth.double().numpy())

    def render_rgb(self, c2w: np.ndarray) -> np.ndarray:
        """The image alone (H, W, 3), sRGB-encoded, clamped to [0, 1]: what a
        blurred frame's sub-frames need. On the CPU backend the forward-only
        renderer (:class:`gs2e.splat.forward.ForwardRenderer`: no alpha, depth
        or autograd; float32, the same bits as :meth:`render_pose`'s image);
        otherwise :meth:`render_pose`'s image."""
        if self.backend != "cpu":
            return self.render_pose(c2w)[0]
        if self._forward is None:
            from gs2e.splat.forward import ForwardRenderer

            self._forward = ForwardRenderer(self.params, self.sh_degree, self.fx, self.fy, self.cx,
                                            self.cy, self.width, self.height,
                                            background=self.bg.tolist(), window=self.window)
        self.renders += 1
        return np.clip(self._forward.render(c2w), 0.0, 1.0)  # a copy: the renderer reuses its buffer

    def rgb_at(self, t_us: float) -> np.ndarray:
        """The image (H, W, 3) at time ``t_us``, sRGB-encoded, clamped to [0,
        1]: :meth:`render_rgb` of its pose for a model with the cut window;
        for one with the smooth window the continuous render
        (:class:`gs2e.splat.forward.ContinuousRenderer`: depth orders held at
        knots ``order_step_px`` apart and cross-faded), which the event stage
        renders too."""
        if self.window == "cut":
            return self.render_rgb(self.pose(t_us))
        if self._continuous is None:
            from gs2e.splat.forward import ContinuousRenderer, order_knots

            self.render_rgb(self.pose(t_us))  # builds the forward renderer
            self._continuous = ContinuousRenderer(
                self._forward, self.pose,
                order_knots(self._forward, self.pose, self.t0_us, self.t1_us, self.order_step_px),
                self.t1_us)
        self.renders += 1
        return np.clip(self._continuous.render(t_us), 0.0, 1.0)

    def render_at(self, t_us: float):
        return self.render_pose(self.pose(t_us))

    def linear_luminance(self, t_us: float) -> np.ndarray:
        """(H, W) float32 linear luminance in [0, 1] at time t_us."""
        rgb = self.render_at(t_us)[0]
        return luminance(srgb_to_linear(rgb)).astype(np.float32)

    def gaussian_centres(self, min_opacity: float = 0.1, max_points: int = 20000, seed: int = 0) -> np.ndarray:
        """Centres of opaque Gaussians (a subsample), for motion estimates."""
        m = self.params["means"].numpy().astype(np.float64)
        op = 1 / (1 + np.exp(-self.params["opacity_logits"].numpy().astype(np.float64)))
        m = m[op >= min_opacity]
        if len(m) > max_points:
            m = m[np.random.default_rng(seed).choice(len(m), max_points, replace=False)]
        return m
