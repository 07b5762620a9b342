"""The factor-effect check (pokeworld.swm.factor_effect) on a stand-in environment, no swm needed: a factor the
dynamics read has an effect, one they ignore (a density overridden by an explicit mass) reads as inert."""

import numpy as np

from pokeworld.swm.factor_effect import effects_in, inert_words, low_dim


class Box:
    def __init__(self, low, high, shape=(1,)):
        self.low, self.high, self.shape, self.dtype = np.full(shape, low), np.full(shape, high), shape, np.float32


class PointMass:
    """A pushed point mass: ``body.mass`` divides the push, ``body.density`` is ignored (as MuJoCo ignores a geom's
    density when the geom sets its mass), ``body.shape`` has no numeric range."""

    def __init__(self, noise: float = 0.0):
        self.action_space = Box(-1.0, 1.0)
        self.variation_space = {"body": {"mass": Box(0.5, 1.5), "density": Box(500.0, 1500.0), "shape": object(),
                                         "gain": Box(1.0, 1.0)}}
        self.unwrapped, self.noise, self.rng = self, noise, np.random.default_rng(123)

    def reset(self, seed=None, options=None):
        key, value = next(iter(options["variation_values"].items()))
        self.mass = float(value[0]) if key == "body.mass" else 1.0
        self.x, self.v = np.random.default_rng(seed).normal(size=2)
        return {"state": np.array([self.x, self.v]), "pixels": np.zeros((32, 32, 3))}, {}

    def step(self, action):
        self.v += 0.1 * float(action[0]) / self.mass + self.noise * self.rng.normal()
        self.x += 0.1 * self.v
        return {"state": np.array([self.x, self.v]), "pixels": np.zeros((32, 32, 3))}, 0.0, False, False, {}


def test_a_read_factor_has_an_effect_and_an_ignored_one_is_inert():
    got = effects_in(PointMass(), ("body.mass", "body.density", "body.shape", "body.gain"), steps=20, seeds=(0, 1))
    assert got["body.mass"]["effect"] > 0.01 and got["body.mass"]["repeat"] == 0 and not got["body.mass"]["inert"]
    assert got["body.density"]["effect"] == 0 and got["body.density"]["inert"]
    assert got["body.shape"]["inert"] is None  # no range to move across: unmeasured, not inert
    assert got["body.gain"]["inert"] is None and "single value" in got["body.gain"]["unmeasured"]
    words = inert_words(got)
    assert len(words) == 1 and words[0].startswith("body.density changed none of the non-pixel observations")


def test_a_noisy_simulator_is_not_called_inert_or_effective_by_its_noise():
    got = effects_in(PointMass(noise=1.0), ("body.density",), steps=20, seeds=(0,))
    assert got["body.density"]["repeat"] > 0 and got["body.density"]["inert"]  # differences at the repeat's size


def test_low_dim_keeps_small_numeric_arrays_and_drops_pixels():
    assert low_dim({"pixels": np.zeros((32, 32, 3)), "b": np.array([2.0]), "a": np.array([1.0, 3.0])}).tolist() == \
        [1.0, 3.0, 2.0]
