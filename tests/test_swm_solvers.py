"""pokeworld.swm.solvers finds stable-worldmodel's solvers in its 0.1.1 layout (``swm.solver``, first argument
``model``) and in its next one (``swm.planning``, first argument ``cost``). Fake packages stand in for both here,
so the core environment tests it without the extra; tests/swm/test_solvers.py runs it against the real 0.1.1."""

import sys
import types
from dataclasses import dataclass

import pytest

from pokeworld.errors import ConfigError
from pokeworld.swm import solvers


@dataclass
class PlanConfig:
    horizon: int
    receding_horizon: int = 1
    warm_start: bool = True


def solver_classes(first: str) -> dict[str, type]:
    """CEM / iCEM / MPPI classes whose first parameter is called ``first`` (and must be given)."""
    def init(self, *args, **kwargs):
        if not args and first not in kwargs:
            raise TypeError(f"missing {first}")
        self.cost, self.options = (args[0] if args else kwargs.pop(first)), kwargs

    return {n: type(n, (), {"__init__": init}) for n in ("CEMSolver", "ICEMSolver", "MPPISolver")}


@pytest.fixture
def released():
    """stable-worldmodel 0.1.1's layout: swm.solver.CEMSolver(model, ...), swm.PlanConfig."""
    swm = types.ModuleType("fake_swm_released")
    swm.solver = types.SimpleNamespace(**solver_classes("model"))
    swm.PlanConfig = PlanConfig
    return swm


@pytest.fixture
def next_layout(monkeypatch):
    """The next layout: stable_worldmodel.planning.solver, re-exported as swm.planning.CEMSolver(cost, ...);
    ``planning`` is a submodule the package does not import itself, and there is no swm.solver any more."""
    swm = types.ModuleType("fake_swm_next")
    planning = types.ModuleType("fake_swm_next.planning")
    for name, cls in solver_classes("cost").items():
        setattr(planning, name, cls)
    planning.PlanConfig = PlanConfig
    monkeypatch.setitem(sys.modules, "fake_swm_next", swm)
    monkeypatch.setitem(sys.modules, "fake_swm_next.planning", planning)
    return swm


@pytest.mark.parametrize("layout", ["released", "next_layout"])
def test_every_solver_is_built_in_both_layouts(layout, request):
    swm = request.getfixturevalue(layout)
    cost = object()
    for name in ("cem", "icem", "mppi"):
        solver = solvers.make_solver(swm, name, cost, num_samples=8, topk=2)
        assert type(solver).__name__ == solvers.SOLVER_CLASSES[name]
        assert solver.cost is cost and solver.options == {"num_samples": 8, "topk": 2}
    assert solvers.plan_config(swm, horizon=2, receding_horizon=1) == PlanConfig(2, 1)


def test_a_layout_without_solvers_or_an_unknown_solver_is_one_clear_error(released):
    empty = types.ModuleType("fake_swm_empty")
    with pytest.raises(ConfigError, match="no CEMSolver.*pip install stable-worldmodel=="):
        solvers.make_solver(empty, "cem", object())
    with pytest.raises(ConfigError, match="no PlanConfig"):
        solvers.plan_config(empty, horizon=2)
    with pytest.raises(ConfigError, match="unknown solver 'gd'"):
        solvers.make_solver(released, "gd", object())
