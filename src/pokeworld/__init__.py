"""pokeworld: physical-parameter identifiability in multimodal latent world models.

Subpackages: ``sim`` (the PokeWorld simulator, sensors, policies, gymnasium
envs), ``models`` (X-JEPA), ``evaluate`` (probes and the identifiability map),
``real`` (RH20T). See README.md and docs/design.md.
"""

__version__ = "0.1.0"
