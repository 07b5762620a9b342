"""The two readings of "normal damping at zeta of critical": restitution against an independent integration, what
stiffness leaves after contact under each, and stores made before the law was recorded still read as what they are."""

import dataclasses

import numpy as np
import pytest

from pokeworld.errors import ConfigError
from pokeworld.sim import PhysicsConfig, contact, environments
from pokeworld.sim.generate import LEGACY_PHYSICS, content_config, generator_config, make_config

# the contact law alone: no finger damping, no drag
# (the calibrated environment's kernel, which these two laws were built for; tests/test_reference_env.py tests the
# reference's hertz law)
TWO_BODY = dataclasses.replace(environments.physics("calibrated"), touch_noise=0.0, finger_damping=0.0,
                               contact_damping="constant")
MU = 0.5  # reduced mass of the unit finger and a unit object


@pytest.mark.parametrize("law", ["constant", "tangent"])
def test_simulated_restitution_matches_the_integrated_law(law):
    ks, v = np.array([500.0, 2000.0, 6000.0]), 0.5
    e = contact.restitution(dataclasses.replace(TWO_BODY, contact_damping=law), ks, 1.0, v)
    reference = [contact.restitution_reference(law, k, MU, v, TWO_BODY.contact_zeta) for k in ks]
    np.testing.assert_allclose(e, reference, atol=0.01)  # semi-implicit Euler at the physics' own sub-step


def test_restitution_falls_with_stiffness_under_the_constant_law_only():
    ks = np.array([500.0, 6000.0])
    constant = contact.restitution(TWO_BODY, ks, 1.0, 0.5)
    tangent = contact.restitution(dataclasses.replace(TWO_BODY, contact_damping="tangent"), ks, 1.0, 0.5)
    assert constant[0] / constant[1] > 1.25  # a soft contact returns more of the impact speed
    assert tangent[0] / tangent[1] == pytest.approx(1.0, abs=0.01)  # scale-free: stiffness leaves no trace
    # the reference agrees on both claims, independently of the simulator
    ref = {law: [contact.restitution_reference(law, k, MU, 0.5, 0.25) for k in ks] for law in ("constant", "tangent")}
    assert ref["constant"][0] / ref["constant"][1] > 1.25
    assert ref["tangent"][0] == pytest.approx(ref["tangent"][1], rel=1e-4)


def test_a_bad_contact_law_is_refused():
    with pytest.raises(ConfigError, match="contact_damping"):
        PhysicsConfig(contact_damping="viscous")


def test_impact_speeds_reads_contact_onsets_of_a_planted_corpus():
    labels = {"contact": np.array([[0, 0, 1, 1, 0, 1]], np.float32),
              "finger_pos": np.zeros((1, 6, 2), np.float32), "object_pos": np.tile([[0.15, 0.0]], (1, 6, 1)),
              "finger_vel": np.tile([[2.0, 1.0]], (1, 6, 1)), "object_vel": np.tile([[0.5, 0.0]], (1, 6, 1))}
    # two onsets (steps 2 and 5), each read at the step before: (2 - 0.5) along +x
    np.testing.assert_allclose(contact.impact_speeds(labels), [1.5, 1.5])


def test_stores_made_before_the_law_was_recorded_read_as_tangent():
    # the calibrated environment's law: the manifest of a store made before the field
    recorded = content_config(make_config("tiny", environment="calibrated"))
    assert "contact_damping" not in recorded["physics"]
    assert generator_config({"config": recorded}).physics.contact_damping == LEGACY_PHYSICS["contact_damping"]
    constant = content_config(make_config("tiny", environment="calibrated", physics={"contact_damping": "constant"}))
    assert constant["physics"]["contact_damping"] == "constant" and constant != recorded  # never taken for one
    assert generator_config({"config": constant}).physics.contact_damping == "constant"


def test_a_map_generates_its_corpora_under_the_law_it_names(tmp_path):
    from pokeworld import experiments
    from pokeworld.data import read_manifest
    from pokeworld.experiments.stages import ensure_corpus

    for law in ("constant", "tangent"):
        c = experiments.make_config("tiny", out=str(tmp_path / law), contact_damping=law, environment="calibrated")
        manifest = read_manifest(ensure_corpus(c, "standard"))
        assert generator_config(manifest).physics.contact_damping == law
    with pytest.raises(ConfigError, match="contact_damping"):
        experiments.make_config("tiny", contact_damping="viscous")
