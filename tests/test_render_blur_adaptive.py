"""The adaptive exposure average of blurred frames (render.blur_tolerance_db):
nested sub-frame times, convergence against the exact box filter, reuse of the
sharp frame, clipping at the trajectory's ends, and on rendered frames."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gs2e.common.color import linear_to_srgb, srgb_to_linear
from gs2e.render.blur import adaptive_blur

X = np.arange(200) + 0.5  # pixel centres of a 1 x 200 image


def _edge(pos_px: float) -> np.ndarray:
    """A hard vertical edge: white left of pos_px (pixel coverage), black right."""
    lin = np.clip(pos_px - (X - 0.5), 0.0, 1.0)
    return linear_to_srgb(np.repeat(lin[None, :, None], 3, axis=2))


def _exact_box(x0: float, x1: float) -> np.ndarray:
    """The edge's time average (linear light) as it sweeps from x0 to x1 at
    constant speed: integrated on a 20,000-step grid."""
    s = np.linspace(x0, x1, 20001)
    acc = np.mean([srgb_to_linear(_edge(p)) for p in s[::10]], axis=0)
    return linear_to_srgb(acc)


def _psnr(a, b):
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0 else -10 * math.log10(mse)


class Counter:
    def __init__(self, f):
        self.f, self.calls = f, []

    def __call__(self, t):
        self.calls.append(t)
        return self.f(t)


def test_converges_to_the_exposure_integral_with_more_slices_for_more_motion():
    E, t = 20_000.0, 50_000.0
    results = {}
    for motion in (4.0, 40.0, 120.0):
        speed = motion / E  # px per us
        render = Counter(lambda tk, s=speed: _edge(40.0 + s * tk - s * (t - E / 2)))
        img, used, n = adaptive_blur(render, t, E, (0.0, 1e6), 55.0, 256, known={t: render(t)})
        exact = _exact_box(40.0, 40.0 + motion)
        results[motion] = (n, used, _psnr(img, exact))
        # the sharp frame came from `known`: rendered once, above, not again
        assert render.calls.count(t) == 1
        assert used == n + 1 and len(set(render.calls)) == n + 1
    ns = [results[m][0] for m in (4.0, 40.0, 120.0)]
    assert ns[0] < ns[1] < ns[2], results
    for motion, (n, used, q) in results.items():
        assert q >= 55.0, (motion, results)  # closer to the integral than the stopping change
    # a fixed 2-slice average of the fastest sweep is far off: the refinement did the work
    render = lambda tk: _edge(40.0 + 120.0 / E * (tk - t + E / 2))  # noqa: E731
    img2, _, _ = adaptive_blur(render, t, E, (0.0, 1e6), 55.0, 2)
    assert _psnr(img2, _exact_box(40.0, 160.0)) < 30.0


def test_static_image_stops_after_one_doubling_and_is_exact():
    img = np.random.default_rng(0).random((6, 7, 3))
    render = Counter(lambda tk: img)
    out, used, n = adaptive_blur(render, 1000.0, 400.0, (0.0, 2000.0), 60.0, 64)
    assert n == 4 and used == 5
    np.testing.assert_allclose(out, img, atol=1e-12)


def test_cap_and_clipping_at_the_trajectory_end():
    E, t, t1 = 20_000.0, 95_000.0, 100_000.0  # the exposure runs 5 ms past the end
    speed = 200.0 / E
    render = Counter(lambda tk: _edge(20.0 + speed * tk - speed * 80_000.0))
    out, used, n = adaptive_blur(render, t, E, (0.0, t1), 200.0, 16)  # tolerance never met
    assert n == 16
    assert max(render.calls) == t1  # times past the end are the end pose
    # 17 nested times 1.25 ms apart from 85 ms: the 13th is t1, the last 4 clip onto it
    assert used == 13 and len(set(render.calls)) == 13
    # the clipped times weigh the end pose as the fixed rule does: 1/4 of the exposure
    # (the edge sweeps 70 -> 220 px until t1, then stays)
    exact = linear_to_srgb(0.75 * srgb_to_linear(_exact_box(70.0, 220.0)) + 0.25 * srgb_to_linear(_edge(220.0)))
    assert _psnr(out, exact) > 35.0


def test_bad_cap_is_refused():
    with pytest.raises(ValueError, match="n_max"):
        adaptive_blur(lambda t: np.zeros((1, 1, 3)), 0.0, 1.0, (0.0, 1.0), 50.0, 1)


def test_render_stage_adaptive_against_fixed_rule_on_a_panned_plane(tmp_path):
    """gs2e render's blurred frames with the adaptive rule and with the fixed
    rule at 1/4 px spacing agree on a fast pan over texture; the sub-frame
    counts recorded are the renders made."""
    import imageio.v3 as iio
    import pandas as pd

    from gs2e.render.settings import RenderSettings
    from gs2e.render.dataset import render_dataset
    from gs2e.testing import plane_model, straight_trajectory

    model = plane_model(tmp_path)
    traj = straight_trajectory(tmp_path, dx=1.2)  # ~1.2 px per 100 ms
    out = {}
    for name, extra in (("adaptive", {"blur_tolerance_db": 55.0}),
                        ("fixed", {"blur_tolerance_db": None, "blur_max_step_px": 0.25, "blur_max_subframes": 256})):
        cfg = RenderSettings.defaults(fps=1.0, exposure_us=900_000.0, write_depth=False, **extra)
        st = render_dataset(model, traj, tmp_path / name, cfg)
        df = pd.read_parquet(tmp_path / name / "frames.parquet")
        out[name] = (st, df)
    st, df = out["adaptive"]
    moving = df[df["n_subframes"] > 1]
    assert len(moving) >= 1 and float(moving["motion_px_p99"].min()) > 8.0
    # renders: one sharp frame per frame plus the blurred frames' other sub-frames
    assert st["renders"] == len(df) + int((df["n_subframes"] - 1).clip(lower=0).sum())
    assert int(moving["n_subframes"].max()) < int(out["fixed"][1]["n_subframes"].max())
    for f in moving["file"]:
        a = iio.imread(tmp_path / "adaptive" / "blur" / f).astype(float) / 255
        b = iio.imread(tmp_path / "fixed" / "blur" / f).astype(float) / 255
        sharp = iio.imread(tmp_path / "adaptive" / "rgb" / f).astype(float) / 255
        assert _psnr(a, b) > 50.0 and _psnr(sharp, b) < _psnr(a, b) - 10.0
