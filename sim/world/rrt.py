"""OMPL's RRT-Connect over some of a robot's joints, with a budget of validity checks
rather than seconds (the same seed plans the same path on any machine), and OMPL's
simplifier to reduce the path found."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

ou.setLogLevel(ou.LOG_NONE)


def rrt_connect(valid: Callable[[np.ndarray], bool], start: np.ndarray, goal: np.ndarray,
                active: Sequence[int], lo: np.ndarray, hi: np.ndarray, rng: np.random.Generator,
                spent: list[int], checks: int, check_step: float, step_range: float
                ) -> np.ndarray | None:
    """A path (k, n) from ``start`` to ``goal`` (n joints each) over the joints
    ``active`` (the others held as at ``start``) within the box ``lo``..``hi`` (n each),
    on which ``valid`` holds for every configuration checked (every ``check_step`` of
    joint space, the tree growing by at most ``step_range``), found before ``spent[0]``
    (the checks counted so far, each call of ``valid`` one more) reaches ``checks``; its
    waypoints reduced by OMPL's simplifier; or None. ``rng`` seeds OMPL's generators (one
    draw, once the goal is found valid)."""
    # RRT-Connect waits for a valid goal until the termination condition, and ours
    # counts validity checks, which waiting does not spend: an invalid goal would hang
    # (this check is not counted: it is the one the goal passed before it was asked for)
    if not valid(goal):
        return None
    active = list(active)
    space = ob.RealVectorStateSpace(len(active))
    bounds = ob.RealVectorBounds(len(active))
    for i, j in enumerate(active):
        bounds.setLow(i, float(lo[j]))
        bounds.setHigh(i, float(hi[j]))
    space.setBounds(bounds)
    ou.RNG.setSeed(int(rng.integers(1, 2 ** 31 - 1)))  # before the planner's generators
    setup = og.SimpleSetup(space)

    def joints_of(state: Any) -> np.ndarray:
        q = start.copy()
        q[active] = [state[i] for i in range(len(active))]
        return q

    def checked(state: Any) -> bool:
        spent[0] += 1
        return valid(joints_of(state))

    def state(q: np.ndarray) -> Any:
        x = space.allocState()
        for i, j in enumerate(active):
            x[i] = float(q[j])
        return x

    setup.setStateValidityChecker(checked)
    info = setup.getSpaceInformation()
    info.setStateValidityCheckingResolution(check_step / space.getMaximumExtent())
    setup.setStartAndGoalStates(state(start), state(goal))
    planner = og.RRTConnect(info)
    planner.setRange(step_range)
    setup.setPlanner(planner)
    setup.solve(ob.PlannerTerminationCondition(lambda: spent[0] >= checks))
    if not setup.haveExactSolutionPath():
        return None
    found = setup.getSolutionPath()
    setup.getPathSimplifier().simplifyMax(found)  # OMPL's shortcutting, as short as it gets
    return np.array([joints_of(found.getState(k)) for k in range(found.getStateCount())])
