"""The tangent pass: a render's time derivative along the camera's motion (issue 67).

For a model of the smooth window (:mod:`gs2e.splat.raster`), the image a
:class:`gs2e.splat.forward.ContinuousRenderer` composes is C1 in time, and its
derivative d image / dt is taken here in forward mode, without a second render:

* **projection** (:func:`projection_tangent`): the 2D centres, conics and
  view-dependent colours of the Gaussians and their derivatives along the view
  matrix's rate dV/dt, by forward-mode automatic differentiation
  (``torch.func.jvp``) through the torch reference projection and colours
  (:func:`gs2e.splat.reference.project_reference`,
  :func:`~gs2e.splat.reference.reference_colors`), which the rasteriser's
  projection matches to rounding (tests/test_splat_raster.py);
* **compositing** (:data:`gs2e.splat.raster.raster_tangent_kernel`, the
  rasteriser's float64 smooth-window kernel with the derivative carried in
  each pixel's state: :func:`gs2e.splat.raster._lane_tangent`): front to back
  over the tile's list in the held depth order, alpha's derivative
  (A e^p - c1) dp/dt and the transmittance's dT/dt = dT (1 - alpha) - T d alpha
  carried along with the colour, the fade r(T) of a pixel's last weights
  differentiated too (the window is C1 in T, so the stop adds no jump); the
  image has the bits of the float64 render;
* **cross-fade**: between two knots' orders, d/dt of (1 - s) A + s B is
  (1 - s) dA + s dB + (ds/dt) (B - A).

What it stands in for: ``events.sampling.slopes: difference`` takes the same
derivative from a second render 2 us later (exact to O(2 us) and float32
rounding) at the cost of a render; here it is exact to float64 rounding, at
the cost of this pass (measured in docs/events.md, "The tangent pass").
"""

from __future__ import annotations

import numpy as np


class _JvpCamera:
    """A camera whose view matrix is a torch tensor carrying a forward-mode
    tangent: what :func:`gs2e.splat.reference.project_reference` reads of a
    :class:`gs2e.splat.rasterize.SplatCamera` (intrinsics, clipping planes and
    ``validate()``, which here returns the tensor itself, tangent kept)."""

    def __init__(self, vm, cam):
        self._vm = vm
        for k in ("fx", "fy", "cx", "cy", "width", "height", "near", "far"):
            setattr(self, k, getattr(cam, k))

    def validate(self):
        return self._vm


def projection_tangent(means, quats, log_scales, sh, sh_degree: int, cam, vm: np.ndarray,
                       dvm: np.ndarray):
    """Projection of Gaussians at the view matrix ``vm`` and its derivative
    along ``dvm``, in forward mode.

    Parameters
    ----------
    means, quats, log_scales : (M, 3), (M, 4), (M, 3) float64 world
        positions, rotations (w, x, y, z) and log standard deviations.
    sh : (M, K, 3) float64 SH coefficients; ``sh_degree`` the active degree.
    cam : the :class:`~gs2e.splat.rasterize.SplatCamera` whose intrinsics,
        size and clipping planes apply (its view matrix is not read).
    vm, dvm : (4, 4) world-to-camera matrix and its rate (per unit of the
        caller's time, e.g. per us).

    Returns
    -------
    (means2d (M, 2) px, conics (M, 3), colors (M, 3)) and their derivatives
    (the same shapes, per unit time), float64 numpy. Culled rows (behind the
    near plane, degenerate) hold stand-in values the caller does not draw.
    """
    import torch
    from torch.func import jvp

    from gs2e.splat.reference import project_reference, reference_colors

    def t(a):
        return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64)

    M, Q, S, SH = t(means), t(quats), t(log_scales), t(sh)

    def f(v):
        m2, con, _, _ = project_reference(M, Q, S, _JvpCamera(v, cam))
        campos = -(v[:3, :3].T @ v[:3, 3])
        return m2, con, reference_colors(M, SH, campos, int(sh_degree))

    with torch.no_grad():
        primal, tangent = jvp(f, (t(vm),), (t(dvm),))
    return tuple(x.numpy() for x in primal), tuple(x.numpy() for x in tangent)
