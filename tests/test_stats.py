"""Corpus statistics: correct on planted trajectories, and the default corpus stays calibrated."""

import numpy as np
import pytest

from pokeworld.data import Dataset
from pokeworld.errors import DataError
from pokeworld.sim.generate import make_config, simulate
from pokeworld.sim.stats import PAPER_STATS, corpus_stats, format_stats, within_tolerance
from pokeworld.windows import glide_frames


def _planted(pos, vel, contact, gamma):
    E, T1 = pos.shape[:2]
    return Dataset(frames=np.zeros((E, T1, 8, 8), np.uint8), proprio=np.zeros((E, T1, 4), np.float32),
                   touch=np.zeros((E, T1, 7), np.float32), actions=np.zeros((E, T1 - 1, 2), np.float32),
                   labels={"object_pos": pos.astype(np.float32), "object_vel": vel.astype(np.float32),
                           "contact": contact.astype(np.float32)},
                   params={"gamma": np.asarray(gamma, np.float32)}, split=np.zeros(E, np.int8),
                   manifest={"config": {"physics": {"dt": 0.05, "object_radius": 0.09, "arena": 1.0}}})


def test_static_displacements_of_constant_velocity_motion():
    T1, v = 41, 0.2
    t = np.arange(T1) * 0.05
    pos = np.stack([0.2 + v * t, np.full(T1, 0.5)], -1)[None].repeat(3, 0)
    vel = np.tile([v, 0.0], (3, T1, 1))
    contact = np.ones((3, T1))  # touching throughout: no glide windows or frames
    st = corpus_stats(_planted(pos, vel, contact, [1.0, 2.0, 3.0]))
    assert st["static16"] == pytest.approx(v * 16 * 0.05, rel=1e-5)
    assert st["static8"] == pytest.approx(v * 8 * 0.05, rel=1e-5)
    assert st["glide_windows"] == 0 and st["glide_loss_share"] == 0.0


def test_glide_reference_is_exact_at_the_median_and_off_elsewhere():
    T1, v0, gammas = 33, 0.6, np.array([1.0, 2.0, 3.0])
    t = np.arange(T1) * 0.05
    # exact exponential glides along x from the arena centre-left, no contact, no walls
    x = 0.3 + v0 * (1 - np.exp(-gammas[:, None] * t)) / gammas[:, None]
    pos = np.stack([x, np.full_like(x, 0.5)], -1)
    vel = np.stack([v0 * np.exp(-gammas[:, None] * t), np.zeros_like(x)], -1)
    st = corpus_stats(_planted(pos, vel, np.zeros((3, T1)), gammas))
    assert st["glide_windows"] == 3 * 3  # every window of every episode is a pure glide
    # the median-gamma reference is exact for the median episode and wrong for the two others
    T = 0.8
    expected = []
    for g in gammas:
        for s in (0, 4, 8):
            i = s + 7
            p0, v = x[list(gammas).index(g), i], vel[list(gammas).index(g), i, 0]
            truth = x[list(gammas).index(g), i + 16]
            expected.append(abs(p0 + v * (1 - np.exp(-2.0 * T)) / 2.0 - truth))
    assert st["glide_median_gamma16"] == pytest.approx(np.mean(expected), rel=1e-4)
    assert st["glide_median_gamma16"] < 0.5 * st["glide_static16"]
    # glide frames: every frame after t = 0 whose speed is still above 0.02 (no contact, no walls here)
    assert st["glide_loss_share"] == pytest.approx((vel[:, 1:, 0] > 0.02).mean(), rel=1e-6)
    assert 0.5 < st["glide_loss_share"] < 1.0


def test_glide_frames_fall_back_to_the_touch_flag_without_labels():
    ds = _planted(np.zeros((1, 30, 2)) + 0.5, np.zeros((1, 30, 2)), np.zeros((1, 30)), [1.0])
    ds.labels = {}
    ds.touch[0, 10:, 6] = 1.0
    g = glide_frames(ds)
    assert g[0, :10].all() and not g[0, 10:].any()


def test_stats_refuse_stores_without_object_labels():
    ds = _planted(np.zeros((1, 30, 2)), np.zeros((1, 30, 2)), np.zeros((1, 30)), [1.0])
    ds.labels = {}
    with pytest.raises(DataError, match="object_pos"):
        corpus_stats(ds)


@pytest.mark.parametrize("corpus", ["standard", "open_loop"])
def test_calibrated_environment_stays_calibrated(corpus):
    # 400 render-free episodes: the calibrated environment must keep every statistic in its band, with a fifth of
    # the program slots open-loop too (the planner's programs; docs/design.md, "Planning: open-loop behaviour ...")
    ds = simulate(make_config("cpu", num_episodes=400, seed=3, corpus=corpus, environment="calibrated"),
                  progress=False, render=False)
    st = ds.manifest["stats"]
    assert st == corpus_stats(ds)
    table = format_stats(st)
    for name in PAPER_STATS:
        assert within_tolerance(name, st[name], CALIBRATION_TOLERANCE.get(name, 0.15)), table


#: statistics the impact-rich calibration does not bring within ±15 % (docs/design.md, "Calibration": strike-retreat
#: dominates so that the certificates reach the paper's, which shortens and thins the glides); the band we
#: reach instead over seeds 0-3, so that a regression (e.g. the pre-calibration 0.075 glide static) is still caught
CALIBRATION_TOLERANCE: dict[str, float] = {"glide_static16": 0.4, "glide_median_gamma16": 0.6,
                                           "glide_loss_share": 0.55}
