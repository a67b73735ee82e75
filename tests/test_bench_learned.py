"""PIE-Net and PIE-Net-Lite (gs2e.bench.learned): the shipped networks on hard
inputs, the same bytes whatever the thread count, a moving texture recovered
from its events, EVREAL's robust normalisation, and the config's check."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from gs2e.bench.learned import VARIANTS, reconstruct_learned, robust_normalize
from gs2e.events.models import Events
from gs2e.events.settings import event_settings


def _random_events(n: int, shape: tuple[int, int], t_max_us: int, seed: int = 0) -> Events:
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, t_max_us, n)).astype(np.int64)
    return Events(t, rng.integers(0, shape[1], n).astype(np.uint16),
                  rng.integers(0, shape[0], n).astype(np.uint16), rng.integers(0, 2, n).astype(np.uint8))


@pytest.mark.parametrize("name", list(VARIANTS))
def test_no_events_one_interval_and_an_odd_size(name):
    """A valid but unusual input: no events at all, a size no pooling divides."""
    one = list(reconstruct_learned(name, Events.empty(), (37, 53), [0, 1000]))
    assert len(one) == 1 and one[0].shape == (37, 53) and one[0].dtype == np.float32
    three = list(reconstruct_learned(name, Events.empty(), (37, 53), [0, 10, 20, 30]))
    assert len(three) == 3
    for img in one + three:
        assert np.isfinite(img).all() and img.min() >= 0.0 and img.max() <= 1.0
    # the recurrence restarts at every call: the first step is the same
    np.testing.assert_array_equal(one[0], three[0])


def test_same_bytes_whatever_the_thread_count():
    ev = _random_events(20_000, (61, 83), 100_000)
    t = np.linspace(0, 100_000, 6).astype(np.int64)
    before = torch.get_num_threads()
    try:
        out = {}
        for threads in (2, 1):
            torch.set_num_threads(threads)
            out[threads] = [np.stack(list(reconstruct_learned(n, ev, (61, 83), t))) for n in VARIANTS]
            assert torch.get_num_threads() == threads  # restored after each step
    finally:
        torch.set_num_threads(before)
    for a, b in zip(out[1], out[2]):
        np.testing.assert_array_equal(a, b)


def test_a_moving_texture_is_recovered_from_its_events():
    """Ideal events of a photograph sliding 0.5 px per frame: after a few frames
    the reconstruction follows the image (correlation > 0.5), which the same
    network without those events does not."""
    from skimage import data

    from gs2e.common.color import srgb_to_linear
    from gs2e.config import load_section
    from gs2e.events.models import make_model

    img = data.camera()[::4, ::4] / 255.0  # 128 x 128, sRGB
    H, W = 64, 96

    def frame(dx: float) -> np.ndarray:
        i, f = int(np.floor(10 + dx)), 10 + dx - np.floor(10 + dx)
        return (1 - f) * img[20:20 + H, i:i + W] + f * img[20:20 + H, i + 1:i + 1 + W]

    sub = 10  # simulator samples per frame
    ts = np.arange(20 * sub + 1, dtype=np.int64) * 500
    lin = np.stack([srgb_to_linear(frame(0.05 * k)) for k in range(len(ts))]).astype(np.float32)
    cfg = {**load_section("events"), "model": "ideal", "theta_on": 0.2, "theta_off": 0.2}
    ev = make_model(event_settings(cfg), (H, W), 0)[0].simulate(ts, lin)
    assert len(ev) > 10_000
    for name in VARIANTS:
        outs = list(reconstruct_learned(name, ev, (H, W), ts[::sub]))
        blind = list(reconstruct_learned(name, Events.empty(), (H, W), ts[::sub]))
        k = 10
        target = frame(0.05 * sub * (k + 1)).ravel()
        corr = np.corrcoef(outs[k].ravel(), target)[0, 1]
        corr_blind = np.corrcoef(blind[k].ravel(), target)[0, 1]
        assert corr > 0.5 and corr > corr_blind + 0.3, (name, corr, corr_blind)


def test_robust_normalize_is_evreal_s():
    img = np.linspace(0.2, 0.6, 10_001).reshape(1, -1)
    out = robust_normalize(img)
    lo, hi = np.percentile(img, [1, 99])
    np.testing.assert_allclose(out, np.clip((img - lo) / (hi - lo), 0, 1), atol=1e-6)
    assert out.dtype == np.float32 and out.min() == 0.0 and out.max() == 1.0
    flat = np.full((4, 5), 0.3)
    np.testing.assert_array_equal(robust_normalize(flat), flat.astype(np.float32))


def test_config_names_the_key_when_the_package_is_missing(monkeypatch):
    import importlib.util

    from gs2e.common.errors import ConfigError
    from gs2e.config import load_config

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "pie_net" else real(name, *a))
    with pytest.raises(ConfigError, match=r"bench.video_learned=.*--no-deps event-pienet"):
        load_config({})
    load_config({"bench": {"video_learned": []}})
