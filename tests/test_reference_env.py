"""The reference environment (the default): the authors' released simulator's laws, behaviour and splits, and the
calibrated environment still reachable with its stores' configs unchanged."""

import dataclasses

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.sim import ParamRanges, PhysicsConfig, PokeWorldSim, contact, environments, fidelity
from pokeworld.sim.generate import content_config, generator_config, make_config, simulate
from pokeworld.sim.policy import PolicyConfig, make_policy

REFERENCE = environments.physics("reference")
CALIBRATED = environments.physics("calibrated")
LAW_ALONE = dataclasses.replace(REFERENCE, touch_noise=0.0, finger_damping=0.0)


def test_reference_is_the_default_and_the_calibrated_layer_restores_the_previous_constants():
    assert PhysicsConfig() == REFERENCE and PolicyConfig() == environments.policy("reference")
    assert (REFERENCE.force_max, REFERENCE.finger_damping, REFERENCE.speed_cap) == (6.0, 2.0, 3.0)
    assert (CALIBRATED.force_max, CALIBRATED.finger_damping, CALIBRATED.speed_cap) == (5.6, 0.85, 0.0)
    assert CALIBRATED.calibrated_dynamics and not REFERENCE.calibrated_dynamics
    with pytest.raises(ConfigError, match="environment"):
        make_config("tiny", environment="gym")
    with pytest.raises(ConfigError, match="walls"):
        PhysicsConfig(walls="rubber")


def test_hertz_restitution_rises_with_stiffness_and_matches_the_integrated_law():
    ks = np.array([500.0, 1732.0, 6000.0])
    e = contact.restitution(LAW_ALONE, ks, 1.22, 1.3)
    assert e[0] < e[1] < e[2]  # a stiff contact loses less of the impact speed: stiffness shows after contact
    mu = 1.22 / 2.22
    np.testing.assert_allclose(e, [contact.restitution_reference("hertz", k, mu, 1.3, 0.25) for k in ks], atol=0.01)
    np.testing.assert_allclose(e, [0.74, 0.77, 0.79], atol=0.01)  # the reference simulator's, issue 59
    # the calibrated environment's tangent law: the same at every stiffness
    flat = contact.restitution(dataclasses.replace(CALIBRATED, touch_noise=0.0, finger_damping=0.0), ks, 1.22, 1.3)
    assert np.ptp(flat) < 0.01 and flat[0] == pytest.approx(0.48, abs=0.01)


def _wall_bounce(physics, mass):
    """Object thrown at the left wall at 2 units/s: its speed after the bounce and its deepest wall overlap."""
    s = PokeWorldSim(1, dataclasses.replace(physics, touch_noise=0.0), seed=0)
    s.reset(params={"mass": mass, "gamma": 0.0}, finger_pos=[0.8, 0.8], object_pos=[0.2, 0.5], object_vel=[-2.0, 0])
    deepest = 0.0
    for _ in range(20):
        s.step(np.zeros((1, 2)), render=False)
        deepest = max(deepest, physics.object_radius - s.state[0, 4])
    return s.state[0, 6], deepest


def test_hertz_walls_carry_mass_and_the_calibrated_walls_do_not():
    light, heavy = _wall_bounce(REFERENCE, 0.5), _wall_bounce(REFERENCE, 3.0)
    assert light[0] > 0 and heavy[0] > 0  # both bounced
    assert heavy[1] > 1.5 * light[1]  # the same wall force decelerates a heavier object more slowly
    cal_light, cal_heavy = _wall_bounce(CALIBRATED, 0.5), _wall_bounce(CALIBRATED, 3.0)
    assert cal_light == pytest.approx(cal_heavy, rel=1e-9)  # a mass-independent acceleration


def test_the_speed_cap_bounds_both_bodies():
    free = dataclasses.replace(REFERENCE, finger_damping=0.0, touch_noise=0.0)
    for cap, bound in ((3.0, True), (0.0, False)):
        s = PokeWorldSim(1, dataclasses.replace(free, speed_cap=cap), seed=0)
        s.reset(params={"gamma": 0.0}, finger_pos=[0.2, 0.2], object_pos=[0.3, 0.7], object_vel=[4.0, 0.0],
                finger_vel=[0.0, 2.9])
        s.step(np.array([[0.0, 1.0]]), render=False)  # the finger pushed past the cap, the object launched above it
        speeds = np.linalg.norm(s.state[0, 2:4]), np.linalg.norm(s.state[0, 6:8])
        assert all(v <= 3.0 + 1e-9 for v in speeds) == bound


def test_touch_is_in_raw_force_units_under_the_reference():
    def impact(units):
        s = PokeWorldSim(1, dataclasses.replace(LAW_ALONE, touch_units=units), seed=0)
        s.reset(params={"mass": 1.0, "stiffness": 2000.0}, finger_pos=[0.3, 0.5], object_pos=[0.4505, 0.5],
                finger_vel=[1.0, 0.0])
        s.step(np.zeros((1, 2)), render=False)
        return s.touch_clean[0].copy()
    raw, scaled = impact("raw"), impact("force_max")
    assert raw[2] > 1.0  # a peak force of several units, not a fraction of F_max
    np.testing.assert_allclose(raw[:5], scaled[:5] * REFERENCE.force_max, rtol=1e-9)
    np.testing.assert_array_equal(raw[5:], scaled[5:])
    s = PokeWorldSim(512, REFERENCE, seed=1)
    s.reset()
    s.step(np.zeros((512, 2)), render=False)
    assert np.std(s.touch[:, 0]) == pytest.approx(0.02, rel=0.15)  # noise 0.02 in raw units


def test_reference_strike_is_periodic_six_approaching_four_retreating():
    cfg = PolicyConfig(mode_weights=(0.0, 1.0, 0.0), switch_prob=0.0, mode_noise=(0.0, 0.0, 0.0))
    pol = make_policy(cfg, 1, np.random.default_rng(0))
    pol.reset()
    proprio, obj = np.array([[0.2, 0.5, 0.0, 0.0]]), np.array([[0.6, 0.5]])
    signs = [np.sign(pol.act(proprio, obj, np.zeros(1))[0, 0]) for _ in range(30)]
    runs = np.diff(np.flatnonzero(np.diff(signs))).tolist()  # lengths of the runs between sign changes
    assert set(runs) <= {6, 4} and len(runs) >= 3


def test_rendering_and_splits_are_the_references():
    s = PokeWorldSim(1, REFERENCE, seed=0)
    s.reset(finger_pos=[0.3, 0.3], object_pos=[0.7, 0.7])
    assert s.frames.max() == 255 and 139 <= np.median(s.frames[s.frames > 100][s.frames[s.frames > 100] < 200]) <= 141
    counts = np.bincount(simulate(make_config("tiny", num_episodes=64), progress=False, render=False).split)
    assert counts.tolist() == [40, 16, 8]  # 4,000 / 1,600 / 800 at paper, in proportion
    assert make_config("paper").num_episodes == 6400
    assert make_config("paper", environment="calibrated").num_episodes == 8000


def test_calibrated_stores_keep_their_configs_and_old_manifests_read_as_calibrated():
    old = content_config(make_config("tiny", environment="calibrated"))
    assert "environment" not in old and "walls" not in old["physics"] and "behaviour" not in old["policy"]
    assert old["physics"]["force_max"] == 5.6 and old["split_fractions"] == [0.6, 0.2, 0.2]
    back = generator_config({"config": old})
    assert back.environment == "calibrated" and back.physics == CALIBRATED
    ref = content_config(make_config("tiny"))
    assert ref["environment"] == "reference" and ref["physics"]["walls"] == "hertz" and ref != old
    assert generator_config({"config": ref}).physics == REFERENCE
    # a value given beside the environment wins over its layer, even the reference's own value
    tuned = make_config("tiny", environment="calibrated", physics={"force_max": 7.0}, policy={"launch_fraction": 0.6})
    assert (tuned.physics.force_max, tuned.physics.finger_damping, tuned.policy.launch_fraction) == (7.0, 0.85, 0.6)


def test_fidelity_statistics_read_a_reference_corpus_and_a_planted_one():
    ds = simulate(make_config("tiny", num_episodes=400, seed=2), progress=False, render=False)
    st = fidelity.corpus_statistics(ds)
    assert 0.15 < st["contact_step_fraction"] < 0.5 and 0.35 < st["first_frame_moving"] < 0.85
    assert st["object_speed_p99"] <= 3.0 + 1e-6  # the cap
    # planted: every object glides at 0.2 along x, never touched: all windows glide, none has contact
    E, T1 = ds.labels["object_pos"].shape[:2]
    t = np.arange(T1) * 0.05
    ds.labels["object_vel"] = np.tile(np.array([0.2, 0.0], np.float32), (E, T1, 1))
    ds.labels["object_pos"] = np.stack([0.1 + 0.2 * t, np.full(T1, 0.5)], -1)[None].repeat(E, 0).astype(np.float32)
    ds.labels["contact"] = np.zeros((E, T1), np.float32)
    planted = fidelity.corpus_statistics(ds)
    assert planted["static16"] == pytest.approx(16 * 0.05 * 0.2, rel=1e-5)
    assert planted["glide_window_fraction"] == 1.0 and planted["contact_window_fraction"] == 0.0
    assert planted["contact_step_fraction"] == 0.0 and planted["first_frame_moving"] == 1.0
    assert np.isnan(planted["ridge_log_k"])  # no contact window to fit on: no number
    assert fidelity.verdicts({"static16": 0.205})["static16"]["pass"]
    assert not fidelity.verdicts({"static16": 0.168})["static16"]["pass"]


def test_the_command_line_builds_on_the_environment_it_names():
    from pokeworld.cli import parse_config

    cfg = parse_config("generate", ["--preset", "paper", "--environment", "calibrated", "--physics.force_max", "7"])
    assert cfg.environment == "calibrated" and cfg.num_episodes == 8000 and cfg.policy.behaviour == "calibrated"
    assert (cfg.physics.force_max, cfg.physics.finger_damping) == (7.0, 0.85)  # the flag wins, the rest is its
    assert parse_config("generate", ["--preset", "paper"]).physics == REFERENCE


def test_map_records_without_an_environment_read_back_as_calibrated():
    from pokeworld.experiments.config import MapConfig, recorded_map_config

    assert recorded_map_config({"preset": "cpu"})["environment"] == "calibrated"
    assert recorded_map_config({"environment": "reference"})["environment"] == "reference"
    assert MapConfig().environment == "reference" and MapConfig().contact_damping == ""  # the environment's own law
    with pytest.raises(ConfigError, match="environment"):
        MapConfig(environment="gym")


def test_a_drift_acceleration_obeys_its_law_and_only_the_reference_kernel_has_one():
    """v̇ = a_d − γ v on a free object (the paper's rejected drift construction): from rest the velocity approaches
    a_d / γ as (a_d / γ)(1 − e^{−γ t}), for any mass; no drift, no motion."""
    a, gamma = np.array([0.12, -0.05]), 1.5
    for mass in (0.5, 3.0):
        s = PokeWorldSim(1, LAW_ALONE, seed=0)
        s.reset(params={"gamma": gamma, "mass": mass, "drift": a}, finger_pos=[0.1, 0.1], object_pos=[0.5, 0.5])
        v = []
        for _ in range(20):
            s.step(np.zeros((1, 2)))
            v.append(s.state[0, 6:8].copy())
        t = (np.arange(20) + 1) * LAW_ALONE.dt
        np.testing.assert_allclose(np.array(v), (a / gamma) * (1 - np.exp(-gamma * t))[:, None], rtol=0.01)
    still = PokeWorldSim(1, LAW_ALONE, seed=0)
    still.reset(params={"gamma": gamma}, finger_pos=[0.1, 0.1], object_pos=[0.5, 0.5])
    still.step(np.zeros((1, 2)))
    assert np.all(still.state[0, 6:8] == 0.0)
    with pytest.raises(ConfigError, match="reference environment"):
        PokeWorldSim(1, CALIBRATED, ParamRanges(drift=0.1))
    with pytest.raises(ConfigError, match="reference environment"):
        PokeWorldSim(1, CALIBRATED, seed=0).reset(params={"drift": [0.1, 0.0]})
    with pytest.raises(ConfigError, match="only the reference environment"):  # refused before anything is simulated
        make_config("tiny", corpus="drift_fixed_gamma", environment="calibrated")


def test_drift_corpora_store_their_drift_and_every_other_store_keeps_its_layout():
    drift = simulate(make_config("tiny", corpus="drift", seed=3), render=False)
    fixed = simulate(make_config("tiny", corpus="drift_fixed_gamma", seed=3), render=False)
    plain = simulate(make_config("tiny", seed=3), render=False)
    for ds in (drift, fixed):
        d = np.stack([ds.params["drift_x"], ds.params["drift_y"]])
        assert np.abs(d).max() <= 0.15 and d.std() > 0.05  # U(-0.15, 0.15) per component, per episode
    assert drift.params["gamma"].std() > 0.5 and np.all(fixed.params["gamma"] == np.float32(1.5))
    assert "drift_x" not in plain.params and "drift" not in content_config(make_config("tiny"))["ranges"]
    # the drift is drawn after every other parameter: the same seed's episodes keep their mass, drag and stiffness
    for q in ("mass", "gamma", "stiffness"):
        np.testing.assert_array_equal(drift.params[q], plain.params[q])
