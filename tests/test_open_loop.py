"""Open-loop behaviour slots: the planner's two-knot programs, exactly, at the configured share; a share of 0
leaves every corpus as it was before the mode existed."""

import numpy as np
import pytest

from pokeworld.data import save
from pokeworld.errors import ConfigError
from pokeworld.io import hash_arrays
from pokeworld.sim import MixedPolicy, PhysicsConfig, PokeWorldSim, PolicyConfig
from pokeworld.sim import generate
from pokeworld.sim.policy import KNOT_SD, PROGRAM, programs

#: content hash of ``simulate(make_config("tiny", seed=0))`` from the generator before open-loop slots existed
#: (commit 08564c2); a share of 0 must reproduce it byte for byte, and so must the calibrated environment (the one
#: it was made in) now that the reference environment is the default
TINY_STANDARD_SHA256 = "9f24bb04d9b323955136af13c47abb834652447afd1c08335fd9ee2f8b78670f"
TINY_CONTACT_POOR_SHA256 = "84b95f5a9162cb115986215755931602c95a53bb4dd8097ef4401dd0446db3c2"


def _roll(cfg: PolicyConfig, n=64, slots=4, seed=0):
    """Run the policy in the simulator; returns actions (n, T, 2), the knots and open-loop masks of every slot,
    and the finger-to-object unit vector at each slot's start."""
    sim = PokeWorldSim(n, PhysicsConfig(), seed=seed)
    pol = MixedPolicy(cfg, n, np.random.default_rng(seed))
    _, vel = pol.reset()
    obs = sim.reset(object_vel=vel)
    acts, knots, masks, dirs = [], [], [], []
    for t in range(slots * PROGRAM):
        priv = sim.privileged()
        a = pol.act(obs["proprio"], priv["object_pos"], priv["contact"])
        if t % PROGRAM == 0:
            rel = priv["object_pos"] - priv["finger_pos"]
            dirs.append(rel / np.linalg.norm(rel, axis=1, keepdims=True))
            knots.append(pol.knots.copy())
            masks.append(pol.open_loop.copy())
        acts.append(a)
        obs = sim.step(a, render=False)
    return np.stack(acts, 1), np.stack(knots, 1), np.stack(masks, 1), np.stack(dirs, 1)


def test_open_loop_slots_execute_the_planners_programs_exactly():
    acts, knots, masks, _ = _roll(PolicyConfig(open_loop_share=1.0))
    assert masks.all()
    for j in range(masks.shape[1]):
        np.testing.assert_array_equal(acts[:, j * PROGRAM:(j + 1) * PROGRAM], programs(knots[:, j]))
    # a fresh program every slot, not one program repeated
    assert not np.allclose(knots[:, 0], knots[:, 1])


def test_knots_are_the_cem_proposal_shifted_toward_the_object():
    _, knots, masks, dirs = _roll(PolicyConfig(open_loop_share=1.0, open_loop_aim=0.0), n=512)
    k = knots[masks]
    assert np.abs(k.mean(0)).max() < 0.05 and np.abs(k.std(0) - KNOT_SD).max() < 0.05  # N(0, KNOT_SD²): CEM's first
    _, knots, masks, dirs = _roll(PolicyConfig(open_loop_share=1.0, open_loop_aim=0.89), n=512)
    along = np.concatenate([(knots[..., :2] * dirs).sum(-1), (knots[..., 2:] * dirs).sum(-1)])
    assert abs(along.mean() - 0.89) < 0.05 and abs(along.std() - KNOT_SD) < 0.05


def test_share_sets_the_fraction_of_slots_and_glides_stay_closed():
    _, _, masks, _ = _roll(PolicyConfig(open_loop_share=0.2), n=1000)
    assert abs(masks.mean() - 0.2) < 0.02
    pol_cfg = PolicyConfig(open_loop_share=1.0, glide_fraction=0.5)
    sim_n = 200
    pol = MixedPolicy(pol_cfg, sim_n, np.random.default_rng(1))
    pol.reset()
    pol.act(np.zeros((sim_n, 4)), np.full((sim_n, 2), 0.5), np.zeros(sim_n))
    assert pol.glide.any() and not (pol.open_loop & pol.glide).any() and pol.open_loop[~pol.glide].all()


def _is_program(seg: np.ndarray) -> bool:
    """Whether a stored (16, 2) float32 action segment is a clipped line between two knots."""
    w = np.linspace(0.0, 1.0, PROGRAM)
    for x in seg.T.astype(np.float64):
        free = np.abs(x) < 1 - 1e-6
        if free.sum() >= 2:
            coef = np.linalg.lstsq(np.stack([1 - w[free], w[free]], 1), x[free], rcond=None)[0]
            if not np.allclose(np.clip(coef[0] * (1 - w) + coef[1] * w, -1, 1), x, atol=1e-5):
                return False
        elif np.count_nonzero(np.diff(np.sign(x))) > 1:  # saturated throughout: at most one crossing
            return False
    return True


def test_generated_corpora_hold_programs_only_in_open_loop_slots():
    share = generate.simulate(generate.make_config("tiny", corpus="open_loop", num_episodes=96, batch_envs=96),
                              progress=False, render=False)
    plain = generate.simulate(generate.make_config("tiny"), progress=False, render=False)
    slots = lambda ds: [ds.actions[e, j:j + PROGRAM] for e in range(ds.num_episodes)  # noqa: E731
                        for j in range(0, ds.actions.shape[1], PROGRAM)]
    found = np.mean([_is_program(s) for s in slots(share)])
    assert abs(found - 0.2) < 0.07  # 384 slots at a share of 0.2
    assert not any(_is_program(s) for s in slots(plain))  # closed-loop actions carry noise: never a program


def test_share_zero_leaves_corpora_byte_identical():
    for corpus, digest in (("standard", TINY_STANDARD_SHA256), ("contact_poor", TINY_CONTACT_POOR_SHA256)):
        ds = generate.simulate(generate.make_config("tiny", corpus=corpus, environment="calibrated"), progress=False)
        assert hash_arrays(ds.arrays()) == digest, corpus
        # and the recorded config is the one written before the fields existed, so old stores stay current
        assert not {"open_loop_share", "open_loop_aim"} & set(ds.manifest["config"]["policy"])
    ds = generate.simulate(generate.make_config("tiny", corpus="open_loop", environment="calibrated"), progress=False)
    assert hash_arrays(ds.arrays()) != TINY_STANDARD_SHA256
    assert ds.manifest["config"]["policy"]["open_loop_share"] == 0.2


def test_an_open_loop_corpus_never_passes_for_a_stored_standard_one(tmp_path):
    out = tmp_path / "d"
    cfg = generate.make_config("tiny", out=str(out))
    save(generate.simulate(cfg, progress=False, render=False), out)
    assert generate.run(cfg) == out  # same config: skipped, not regenerated
    with pytest.raises(ConfigError, match="different config"):
        generate.run(generate.make_config("tiny", out=str(out), corpus="open_loop"))


def test_bad_open_loop_share_and_aim_raise():
    with pytest.raises(ConfigError, match="open_loop_share"):
        PolicyConfig(open_loop_share=1.5)
    with pytest.raises(ConfigError, match="open_loop_aim"):
        PolicyConfig(open_loop_aim=-0.5)
