"""PokeWorld: the 2D poking environment with hidden mass, drag and contact stiffness."""

from . import contact, environments
from .core import PARAM_NAMES, ParamRanges, PhysicsConfig, PokeWorldSim
from .envs import PokeWorldEnv, PokeWorldVectorEnv, register
from .policy import MixedPolicy, PolicyConfig

register()

__all__ = ["contact", "environments", "PARAM_NAMES", "ParamRanges", "PhysicsConfig", "PokeWorldSim", "PokeWorldEnv",
           "PokeWorldVectorEnv", "MixedPolicy", "PolicyConfig", "register"]
