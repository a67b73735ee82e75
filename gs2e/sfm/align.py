"""Comparing recovered cameras with ground truth up to a similarity."""

from __future__ import annotations

import numpy as np

from gs2e.common.so3 import geodesic_angle, umeyama


def alignment_errors(c2w_est: np.ndarray, c2w_gt: np.ndarray) -> dict[str, float]:
    """Camera errors after the similarity that best maps estimated camera
    centres onto the ground-truth ones (Umeyama, least squares).

    Parameters
    ----------
    c2w_est, c2w_gt : (N, 4, 4) camera-to-world poses of the same N views,
        OpenCV axes, N >= 3.

    Returns
    -------
    dict with centre errors in ground-truth units (``center_rmse``,
    ``center_median``, ``center_max``), the same relative to the ground-truth
    scene extent (max distance of a centre from the centroid) in percent
    (``center_rmse_pct_extent``), and rotation errors in degrees after
    alignment (``rot_median_deg``, ``rot_max_deg``), and the scale found.
    """
    c_est = c2w_est[:, :3, 3]
    c_gt = c2w_gt[:, :3, 3]
    s, R, t = umeyama(c_est, c_gt, with_scale=True)
    c_al = (s * (R @ c_est.T)).T + t
    err = np.linalg.norm(c_al - c_gt, axis=1)
    extent = float(np.max(np.linalg.norm(c_gt - c_gt.mean(0), axis=1)))
    R_al = R[None] @ c2w_est[:, :3, :3]
    rot = np.degrees(geodesic_angle(R_al, c2w_gt[:, :3, :3]))
    return {
        "center_rmse": float(np.sqrt(np.mean(err ** 2))),
        "center_median": float(np.median(err)),
        "center_max": float(err.max()),
        "center_rmse_pct_extent": float(100 * np.sqrt(np.mean(err ** 2)) / extent) if extent > 0 else float("nan"),
        "rot_median_deg": float(np.median(rot)),
        "rot_max_deg": float(rot.max()),
        "scale": float(s),
    }
