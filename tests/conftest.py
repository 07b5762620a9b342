import os

import numpy as np
import pytest

# Keep the 2-core CI machine responsive and results deterministic.
os.environ.setdefault("OMP_NUM_THREADS", "2")


@pytest.fixture(scope="session")
def tiny_dataset():
    """A small simulated corpus shared by tests that only read it."""
    from pokeworld.sim.generate import make_config, simulate

    return simulate(make_config("tiny", num_episodes=96, batch_envs=96), progress=False)


@pytest.fixture
def rng():
    return np.random.default_rng(0)
