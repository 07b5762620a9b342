"""The self-supervised flow sensor recovers a known translation; the log-speed linear certificate reads γ."""

import numpy as np
import pytest

from pokeworld.certify import linear_sequence_r2
from pokeworld.errors import ConfigError
from pokeworld.models.flow import log_speed, make_config, object_flow, train_flow


def disks(centres: np.ndarray, size: int = 32, radius: float = 3.0) -> np.ndarray:
    """Anti-aliased bright disks at ``centres`` (N, 2) in pixels: (N, size, size) uint8."""
    ys, xs = np.mgrid[0:size, 0:size] + 0.5
    d = np.hypot(xs[None] - centres[:, 0, None, None], ys[None] - centres[:, 1, None, None])
    return (np.clip(radius - d + 0.5, 0, 1) * 255).astype(np.uint8)


def translated_pairs(rng, n: int, size: int = 32, max_shift: float = 2.5):
    c0 = rng.uniform(8, size - 8, (n, 2))
    shift = rng.uniform(-max_shift, max_shift, (n, 2))
    return np.stack([disks(c0, size), disks(c0 + shift, size)], 1), shift


def test_flow_estimator_recovers_a_known_translation():
    frames, _ = translated_pairs(np.random.default_rng(0), 256, size=24)  # trained on frames alone
    net = train_flow(frames, make_config("cpu", steps=200, batch_size=8, width=8, lr=3e-3))
    test, shift = translated_pairs(np.random.default_rng(1), 64, size=24)
    est = object_flow(net, test, arena=24, dt=1.0)[:, 1]  # pixels per step
    err = np.abs(est - shift)
    assert err.mean() < 0.4, err.mean()  # the shifts are up to 2.5 px: a blind estimator errs by ~1.25
    # the stored sensor reloads to the same estimates
    import tempfile
    from pathlib import Path as _P

    from pokeworld.models.flow import load_flow, save_flow

    with tempfile.TemporaryDirectory() as d:
        save_flow(net, _P(d) / "sensor.pt", {"note": "test"})
        again = object_flow(load_flow(_P(d) / "sensor.pt"), test, arena=24, dt=1.0)[:, 1]
    np.testing.assert_allclose(again, est, atol=1e-6)
    assert np.corrcoef(est[:, 0], shift[:, 0])[0, 1] > 0.95 and np.corrcoef(est[:, 1], shift[:, 1])[0, 1] > 0.95
    static = object_flow(net, np.stack([test[:, 0], test[:, 0]], 1), arena=24, dt=1.0)[:, 1]
    assert np.abs(static).mean() < 0.3


def glide_windows(rng, n: int, length: int = 16, dt: float = 0.05):
    gamma = rng.uniform(0.5, 4.0, n)
    v0 = rng.uniform(0.3, 2.0, n)
    t = np.arange(length) * dt
    speed = v0[:, None] * np.exp(-gamma[:, None] * t[None])
    return log_speed(np.stack([speed, np.zeros_like(speed)], -1)), gamma


def test_log_speed_certificate_reads_gamma_on_pure_glides_and_fails_when_shuffled():
    rng = np.random.default_rng(0)
    X_fit, g_fit = glide_windows(rng, 400)
    X_test, g_test = glide_windows(rng, 200)
    groups = np.arange(400) // 4
    assert linear_sequence_r2(X_fit, g_fit, groups, X_test, g_test) > 0.98  # slope of log|v| is -γ
    shuffle = lambda X: np.take_along_axis(X, rng.permuted(np.tile(np.arange(X.shape[1]), (len(X), 1)), axis=1), 1)  # noqa
    assert linear_sequence_r2(shuffle(X_fit), g_fit, groups, shuffle(X_test), g_test) < 0.5
    # in plain speed the same trace is a ratio, not a linear functional: the linear certificate drops
    assert linear_sequence_r2(np.exp(X_fit), g_fit, groups, np.exp(X_test), g_test) < 0.9


def test_bad_flow_configs_raise():
    with pytest.raises(ConfigError):
        make_config("tiny", steps=0)
    with pytest.raises(ConfigError):
        make_config("tiny", smooth_weight=-1.0)
