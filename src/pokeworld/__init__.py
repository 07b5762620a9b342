"""pokeworld: physical-parameter identifiability in multimodal latent world models.

Subpackages: ``sim`` (the PokeWorld simulator, sensors, policies, gymnasium
envs), ``models`` (X-JEPA), ``evaluate`` (probes and the identifiability map),
``real`` (RH20T). See README.md and docs/design.md.
"""

__version__ = "0.1.0"

#: Gymnasium id of the PokeWorld env (``gymnasium.make`` / ``make_vec`` with ``vectorization_mode="vector_entry_point"``).
ENV_ID = "pokeworld/PokeWorld-v0"


def register_envs() -> None:
    """Register :data:`ENV_ID` with gymnasium (idempotent).

    Runs on ``import pokeworld``, as gym-pusht does, so ``import pokeworld; gymnasium.make(ENV_ID)``
    works; the entry points are strings, so the simulator (numba) loads only when an env is made.
    """
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        # Gymnasium's convention: the episode length is the spec's max_episode_steps (the corpus's 64,
        # pokeworld.sim.envs.EPISODE_STEPS), which make's TimeLimit wrapper and make_vec's vector env both apply
        gymnasium.register(id=ENV_ID, entry_point="pokeworld.sim.envs:registered_env",
                           vector_entry_point="pokeworld.sim.envs:PokeWorldVectorEnv",
                           max_episode_steps=64, disable_env_checker=False)


register_envs()
