"""Physics laws, sensors, determinism and input validation of the PokeWorld simulator."""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pokeworld.errors import ConfigError
from pokeworld.sim import PhysicsConfig, PokeWorldSim, environments
from pokeworld.sim.physics import hertz_normal_force

# the laws below are the calibrated environment's (the one every earlier record used): its tests stay pinned to it;
# tests/test_reference_env.py tests the reference environment's laws
CALIBRATED = environments.physics("calibrated")


def calibrated(**changes) -> PhysicsConfig:
    return replace(CALIBRATED, **changes)


FREE = calibrated(touch_noise=0.0, finger_damping=0.0)
TANGENT = calibrated(touch_noise=0.0, finger_damping=0.0, contact_damping="tangent")
CONSTANT, TANGENT_LAW = 0, 1  # the kernels' codes of physics.DAMPING_LAWS


def _sim(n=1, cfg=FREE, **reset):
    s = PokeWorldSim(n, cfg, seed=0)
    s.reset(**reset)
    return s


def test_free_glide_decays_exponentially():
    gamma = 2.7
    s = _sim(params={"gamma": gamma, "mass": 1.3}, finger_pos=[0.1, 0.1], object_pos=[0.3, 0.5],
             object_vel=[1.5, 0.0])
    speeds = [1.5]
    for _ in range(10):
        s.step(np.zeros((1, 2)))
        speeds.append(float(np.linalg.norm(s.state[0, 6:8])))
    t = np.arange(11) * FREE.dt
    np.testing.assert_allclose(speeds, 1.5 * np.exp(-gamma * t), rtol=0.01)


def test_glide_decay_is_mass_independent():
    out = []
    for m in (0.5, 3.0):
        s = _sim(params={"gamma": 1.0, "mass": m}, finger_pos=[0.1, 0.1], object_pos=[0.3, 0.5],
                 object_vel=[1.0, 0.0])
        for _ in range(5):
            s.step(np.zeros((1, 2)))
        out.append(s.state[0, 4:8].copy())
    np.testing.assert_allclose(out[0], out[1], rtol=1e-12)


def test_hertz_force_law():
    k, mu, zeta = 3000.0, 0.5, 0.25
    for d in (1e-4, 1e-3, 5e-3, 2e-2):
        for law in (CONSTANT, TANGENT_LAW):
            assert hertz_normal_force(d, 0.0, k, mu, zeta, law) == pytest.approx(k * d**1.5, rel=1e-12)
        # tangent: damping at zeta of critical for the tangent stiffness 1.5 k sqrt(d)
        c = 2 * zeta * np.sqrt(1.5 * k * np.sqrt(d) * mu)
        assert hertz_normal_force(d, -0.5, k, mu, zeta, TANGENT_LAW) == pytest.approx(k * d**1.5 + 0.5 * c, rel=1e-12)
        # constant: zeta of critical for a spring of constant k, whatever the overlap
        c = 2 * zeta * np.sqrt(k * mu)
        assert hertz_normal_force(d, -0.5, k, mu, zeta, CONSTANT) == pytest.approx(k * d**1.5 + 0.5 * c, rel=1e-12)
    # the tangent damping coefficient vanishes at first touch (the constant one does not)
    assert hertz_normal_force(1e-12, -2.0, k, mu, zeta, TANGENT_LAW) < 1e-2 * 2 * zeta * np.sqrt(k * mu) * 2.0
    assert hertz_normal_force(1e-12, -2.0, k, mu, zeta, CONSTANT) == pytest.approx(2 * zeta * np.sqrt(k * mu) * 2.0,
                                                                                  rel=1e-6)
    for law in (CONSTANT, TANGENT_LAW):
        assert hertz_normal_force(1e-3, 100.0, k, mu, zeta, law) == 0.0  # a penalty contact never pulls


def _reference_restitution(zeta, k, mu, v0):
    """Restitution of mu*d'' = -max(k d^1.5 + 2 zeta sqrt(1.5 k sqrt(d) mu) d', 0), solved accurately."""
    def rhs(_, y):
        d, dd = y
        if d <= 0:
            return [dd, 0.0]
        fn = max(k * d**1.5 + 2 * zeta * np.sqrt(1.5 * k * np.sqrt(d) * mu) * dd, 0.0)
        return [dd, -fn / mu]

    ev = lambda _, y: y[0] + 1e-12  # noqa: E731
    ev.terminal, ev.direction = True, -1
    sol = solve_ivp(rhs, (0, 5), [1e-12, v0], events=ev, rtol=1e-10, atol=1e-12, max_step=1e-4)
    return -sol.y[1, -1] / v0


def _impact(k, m=1.0, v0=1.2, steps=8, cfg=FREE):
    """Finger coasting (no command, no damping) into a resting object: a free two-body impact."""
    s = _sim(cfg=cfg, params={"gamma": 0.0, "mass": m, "stiffness": k}, finger_pos=[0.3, 0.5],
             finger_vel=[v0, 0.0], object_pos=[0.3 + 0.15 + 0.01, 0.5])
    touches, overlaps = [], []
    for _ in range(steps):
        s.step(np.zeros((1, 2)))
        touches.append(s.touch_clean[0].copy())
        overlaps.append(0.15 - np.linalg.norm(s.state[0, 4:6] - s.state[0, 0:2]))
    return s, np.array(touches), np.array(overlaps)


def test_restitution_depends_on_zeta_only_under_the_tangent_law():
    e = {}
    for k, m in ((500.0, 0.5), (600.0, 1.0), (2000.0, 1.5), (6000.0, 3.0)):
        s, touches, _ = _impact(k, m, cfg=TANGENT)
        assert touches[:, 6].max() == 1.0 and touches[-1, 6] == 0.0  # contact happened and ended
        e[(k, m)] = (s.state[0, 6] - s.state[0, 2]) / 1.2
    e_ref = _reference_restitution(0.25, 1000.0, 0.5, 1.2)
    assert 0.3 < e_ref < 0.7  # underdamped impact: a real bounce survives
    for (k, m), v in e.items():
        assert v == pytest.approx(e_ref, rel=0.02), (k, m)
    # the reference itself does not move with k, mu or speed (the law is scale-free in d / d_max)
    assert _reference_restitution(0.25, 6000.0, 0.75, 0.6) == pytest.approx(e_ref, rel=1e-3)


def test_impact_force_peaks_near_maximum_penetration():
    fine = calibrated(touch_noise=0.0, finger_damping=0.0, dt=0.0005, substeps=1)  # one sub-step per step
    peaks = {}
    for k in (500.0, 6000.0):
        _, touches, overlaps = _impact(k, 1.0, 1.2, steps=400, cfg=replace(fine, contact_damping="tangent"))
        f = touches[:, 2]
        on = np.flatnonzero(f > 0)
        # the transient is elastic-dominated: the force at maximum penetration is close to the peak,
        # and the first sub-step of contact (where the old k-only damping peaked) is far below it
        assert f[overlaps.argmax()] > 0.85 * f.max()
        assert f[on[0]] < 0.3 * f.max()
        assert f.argmax() - on[0] > 0.25 * on.size
        peaks[k] = f.max()
    assert peaks[6000.0] > 2 * peaks[500.0]


def test_momentum_conserved_in_impact():
    m, v0 = 2.0, 1.2
    s, touches, _ = _impact(3000.0, m, v0)
    assert touches[:, 6].max() == 1.0  # the impact happened
    p = 1.0 * s.state[0, 2:4] + m * s.state[0, 6:8]
    np.testing.assert_allclose(p, [v0, 0.0], atol=1e-9)


def test_touch_peak_grows_with_stiffness_on_impacts():
    peaks = [_impact(k)[1][:, 2].max() for k in (500.0, 1500.0, 6000.0)]
    assert peaks[0] < peaks[1] < peaks[2]
    assert peaks[2] > 1.5 * peaks[0]


# a strongly damped finger settles a push within 14 steps (0.7 s), well before any wall
PUSH = calibrated(touch_noise=0.0, finger_damping=4.0, force_max=8.0)


def test_quasi_static_push_force_is_stiffness_independent():
    forces = []
    for k in (500.0, 6000.0):
        s = _sim(cfg=PUSH, params={"gamma": 2.0, "mass": 2.0, "stiffness": k},
                 finger_pos=[0.2, 0.5], object_pos=[0.2 + 0.15, 0.5])
        for _ in range(14):
            s.step(np.array([[0.5, 0.0]]))
        forces.append(-s.touch_clean[0, 0])  # reaction on the finger points backwards
    assert forces[0] > 0.05
    assert forces[0] == pytest.approx(forces[1], rel=0.05)


def test_quasi_static_penetration_follows_hertz_and_reveals_stiffness():
    # The push force is k-independent, but the overlap it holds is d = (F/k)^(2/3): this is how
    # stiffness reaches kinematics (and sub-pixel vision), the channel the gru_geom certificate reads.
    overlaps, forces = [], []
    for k in (500.0, 6000.0):
        s = _sim(cfg=PUSH, params={"gamma": 2.0, "mass": 2.0, "stiffness": k},
                 finger_pos=[0.2, 0.5], object_pos=[0.2 + 0.15, 0.5])
        for _ in range(14):
            s.step(np.array([[0.5, 0.0]]))
        f = np.linalg.norm(s.touch_clean[0, 3:5]) * s.cfg.force_max  # end-of-step force, simulator units
        d = 0.15 - np.linalg.norm(s.state[0, 4:6] - s.state[0, 0:2])
        overlaps.append(d)
        forces.append(f)
        assert d == pytest.approx((f / k) ** (2 / 3), rel=0.05)
    assert overlaps[0] / overlaps[1] == pytest.approx((6000 / 500) ** (2 / 3) * (forces[0] / forces[1]) ** (2 / 3),
                                                      rel=0.05)
    assert overlaps[0] * 64 > 1.0 > overlaps[1] * 64  # about 1 px apart on the 64-px frame


def test_renders_identical_across_hidden_parameters():
    frames = []
    for p in ({"mass": 0.5, "gamma": 0.5, "stiffness": 500.0}, {"mass": 3.0, "gamma": 4.0, "stiffness": 6000.0}):
        s = _sim(params=p, finger_pos=[0.3, 0.4], object_pos=[0.6, 0.55])
        frames.append(s.frames[0].copy())
    assert np.array_equal(frames[0], frames[1])
    assert frames[0].max() == 255 and (frames[0] == 128).any()  # object and finger are distinguishable


def test_rendering_is_antialiased_and_tracks_position():
    s = _sim(finger_pos=[0.1, 0.1], object_pos=[0.5, 0.5])
    img = s.frames[0].astype(float)
    assert len(np.unique(img)) > 3  # partial-coverage gray levels at the edges
    obj = img * (img > 150)
    ys, xs = np.nonzero(obj)
    cy = (ys * obj[ys, xs]).sum() / obj.sum()
    cx = (xs * obj[ys, xs]).sum() / obj.sum()
    assert (cx + 0.5) / 64 == pytest.approx(0.5, abs=0.01) and (cy + 0.5) / 64 == pytest.approx(0.5, abs=0.01)


def test_frame_averaged_touch_drops_substep_statistics():
    cfg = calibrated(touch_noise=0.0, finger_damping=0.0, frame_averaged_touch=True)
    s, _, _ = _impact(3000.0, cfg=cfg, steps=3)
    t = s.touch
    np.testing.assert_allclose(t[0, 2], np.linalg.norm(t[0, :2]), rtol=1e-5)
    np.testing.assert_allclose(t[0, 3:5], t[0, :2])


def test_touch_noise_only_on_force_channels():
    s = PokeWorldSim(256, calibrated(touch_noise=0.02), seed=1)
    s.reset()
    s.step(np.zeros((256, 2)))
    noncontact = s.touch_clean[:, 6] == 0
    assert np.std(s.touch[noncontact, :5]) == pytest.approx(0.02, rel=0.1)
    np.testing.assert_array_equal(s.touch[:, 5:], s.touch_clean[:, 5:].astype(np.float32))


def test_walls_keep_bodies_inside():
    s = _sim(n=1, params={"gamma": 0.5}, finger_pos=[0.5, 0.5], object_pos=[0.8, 0.2], object_vel=[3.0, -3.0])
    for _ in range(40):
        s.step(np.array([[1.0, 1.0]]))
        assert 0.0 < s.state[0, 4] < 1.0 and 0.0 < s.state[0, 5] < 1.0
        assert 0.0 < s.state[0, 0] < 1.0 and 0.0 < s.state[0, 1] < 1.0


def test_determinism_same_seed_same_rollout():
    outs = []
    for _ in range(2):
        s = PokeWorldSim(8, calibrated(), seed=42)
        s.reset()
        rng = np.random.default_rng(3)
        for _ in range(10):
            obs = s.step(rng.uniform(-1, 1, (8, 2)))
        outs.append((obs["vision"], obs["touch"], s.state.copy()))
    for a, b in zip(*outs):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("bad", [
    {"params": {"mass": -1.0}}, {"params": {"viscosity": 1.0}}, {"params": {"gamma": float("nan")}},
    {"object_pos": [2.0, 0.5]}, {"finger_pos": [0.5]},
])
def test_bad_reset_options_raise(bad):
    s = PokeWorldSim(1, seed=0)
    with pytest.raises(ConfigError):
        s.reset(**bad)


def test_bad_actions_and_configs_raise():
    s = PokeWorldSim(2, seed=0)
    s.reset()
    with pytest.raises(ConfigError, match="shape"):
        s.step(np.zeros((3, 2)))
    with pytest.raises(ConfigError, match="NaN"):
        s.step(np.array([[np.nan, 0], [0, 0]]))
    with pytest.raises(ConfigError):
        PhysicsConfig(contact_zeta=1.5)
    with pytest.raises(ConfigError):
        PhysicsConfig(dt=0.0)
