"""pokeworld.swm.solvers against the installed stable-worldmodel 0.1.1 (its solvers in swm.solver)."""

import stable_worldmodel as swm

from pokeworld.swm import solvers


def test_the_released_solvers_are_found_and_take_the_cost_first():
    assert solvers.solver_home(swm) is swm.solver
    cost = object()
    for name, cls in solvers.SOLVER_CLASSES.items():
        solver = solvers.make_solver(swm, name, cost, num_samples=8, topk=2, n_steps=1)
        assert isinstance(solver, getattr(swm.solver, cls))
    assert isinstance(solvers.plan_config(swm, horizon=2, receding_horizon=1, warm_start=False), swm.PlanConfig)
