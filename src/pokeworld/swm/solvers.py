"""stable-worldmodel's planning solvers through one import point, for its 0.1.1 release and its next layout.

0.1.1 keeps the solvers in ``stable_worldmodel.solver`` (``swm.solver.CEMSolver``) and names their first argument
``model``; the next layout moves them to ``stable_worldmodel.planning.solver``, re-exported as
``swm.planning.CEMSolver``, and names that argument ``cost``. :func:`make_solver` finds the classes in either
place and hands the cost over positionally, which both signatures accept; :func:`plan_config` does the same for
the solvers' ``PlanConfig``.
"""

from __future__ import annotations

import importlib
from types import ModuleType
from typing import Any

from ..errors import ConfigError
from .require import SWM_VERSION

#: Our solver names -> stable-worldmodel's class names (the same in both layouts).
SOLVER_CLASSES = {"cem": "CEMSolver", "icem": "ICEMSolver", "mppi": "MPPISolver"}

#: Where the solvers may live, newest layout first: an attribute of the package, or a submodule to import.
SOLVER_HOMES = ("planning", "planning.solver", "solver")


def submodule(swm: ModuleType, dotted: str) -> ModuleType | None:
    """``swm.<dotted>`` as an attribute or an importable submodule; None when this release has no such module."""
    obj: Any = swm
    for part in dotted.split("."):
        obj = getattr(obj, part, None)
        if obj is None:
            break
    if obj is not None:
        return obj
    try:
        return importlib.import_module(f"{swm.__name__}.{dotted}")
    except ModuleNotFoundError:
        return None


def solver_home(swm: ModuleType) -> ModuleType:
    """The module that holds stable-worldmodel's solver classes in this release."""
    for dotted in SOLVER_HOMES:
        home = submodule(swm, dotted)
        if home is not None and hasattr(home, SOLVER_CLASSES["cem"]):
            return home
    raise ConfigError(f"this stable-worldmodel ({getattr(swm, '__version__', 'unknown version')}) has no CEMSolver in "
                      f"{', '.join('swm.' + h for h in SOLVER_HOMES)}; install the release the bridge is tested "
                      f"against: pip install stable-worldmodel=={SWM_VERSION}")


def make_solver(swm: ModuleType, name: str, cost: Any, **options: Any) -> Any:
    """stable-worldmodel's solver ``name`` (cem, icem, mppi) planning against ``cost`` with ``options``.

    The cost goes first and positionally: the parameter is ``model`` in 0.1.1 and ``cost`` after it."""
    if name not in SOLVER_CLASSES:
        raise ConfigError(f"unknown solver {name!r}; choose from {list(SOLVER_CLASSES)}")
    return getattr(solver_home(swm), SOLVER_CLASSES[name])(cost, **options)


def plan_config(swm: ModuleType, **fields: Any) -> Any:
    """The solvers' ``PlanConfig`` (horizon, receding horizon, ...) from wherever this release exports it."""
    for dotted in ("", "planning", "policy"):
        home = submodule(swm, dotted) if dotted else swm
        if home is not None and hasattr(home, "PlanConfig"):
            return home.PlanConfig(**fields)
    raise ConfigError(f"this stable-worldmodel has no PlanConfig in swm, swm.planning or swm.policy; install the "
                      f"release the bridge is tested against: pip install stable-worldmodel=={SWM_VERSION}")


__all__ = ["SOLVER_CLASSES", "SOLVER_HOMES", "make_solver", "plan_config", "solver_home", "submodule"]
