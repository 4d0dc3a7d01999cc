"""Global planning with OMPL's geometric planners (RRTConnect, BITstar, ... by name).

The robot is planned as a point in the plane (positions only: a differential drive
with a local MPC turns on the spot) against the costmap's distance field: a point is
valid when its clearance exceeds ``robot_radius + clearance``. Edges are checked
exactly by a vectorised :class:`ompl.base.MotionValidator` (every grid cell a segment
passes through must be valid), so no edge cuts a corner between two checked states.
Planning happens in the grid's own frame (see :class:`FreeSpace`); the callbacks
capture numpy data only, and every OMPL object lives and dies inside one plan.

What OMPL 2.0.1 (PyPI wheel, nanobind) does, as probed for this module:

* Seeding. ``ou.RNG.setSeed(s)`` can be called again after sampling has started:
  OMPL logs "Random number generation already started ..." (silenced here) but still
  reseeds the generator that seeds every RNG created afterwards. Each plan builds a
  fresh space, samplers, planner and simplifier right after reseeding, so a plan is a
  function of (costmap, start, goal, config, seed) whenever the planner is
  single-threaded and stops on its own rather than on the clock: RRTConnect, RRT,
  KPIECE1, ... always; BITstar, RRTstar, ... when they stop on the cost threshold.
  PRM / PRMstar grow their roadmap in a second thread and are not reproducible; nor
  are plans run concurrently from several Python threads (the seed is process-global).
* ``SimpleSetup.solve`` keeps the GIL: a Python callback called from a planner's
  second thread (PRM's solution checker calls the termination condition) deadlocks.
  PRM-like planners therefore only ever get C++ termination conditions here.
* Budgets. A plan stops on a count, never on the clock: the termination condition
  counts its own evaluations (one per planner iteration) up to ``iterations``, so a
  run is byte-identical with or without other processes loading the CPU. Optimising
  planners run in doubling rounds (round k: ``round_iterations * 2**k`` iterations,
  within the same total) and stop once the simplified path is no longer than
  ``cost_threshold`` times a reference length: the any-angle shortest path at the
  same clearance (:class:`cost_grid.CostGridPlanner` with ``cost_weight: 0``). The
  objective carries the same threshold so a planner whose raw cost gets there stops
  inside a round. ``time_limit`` is only a watchdog. The exception is the PRM family
  (PRM, PRMstar, LazyPRM, LazyPRMstar, SPARS, SPARStwo): it grows its roadmap in a
  second thread whatever the termination condition, so it runs on wall-time slices
  and is not reproducible.
* Inflation cost. OMPL samples the free space only; with ``refine`` (the default) its
  solution is then made cost-aware by :meth:`cost_grid.CostGridPlanner.refine`: the
  cheapest path over the inflation cost within a band around OMPL's path (OMPL
  chooses the way round obstacles, the costmap where in the corridor), shortcut and
  filleted. So ``stack.costmap.inflation_radius`` shapes OMPL plans as it does
  cost_grid's.
"""

from __future__ import annotations

import math
import time

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.planners.base import PlannedPath, PlanningError
from agv_mission.planners.configs import CostGridConfig, OmplPlannerConfig
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.free_space import FreeSpace, FreeSpacePlanner
from agv_mission.planners.path_smoothing import path_length

# Anytime, asymptotically optimal planners: worth running past their first solution.
OPTIMIZING_PLANNERS = frozenset(
    {"RRTstar", "InformedRRTstar", "SORRTstar", "BITstar", "ABITstar", "AITstar", "EITstar"}
    | {"PRMstar", "LazyPRMstar", "AORRTC", "RRTXstatic", "LBTRRT", "SPARS", "SPARStwo"}
)
# Planners that evaluate the termination condition from a second thread.
THREADED_PLANNERS = frozenset({"PRM", "PRMstar", "LazyPRM", "LazyPRMstar", "SPARS", "SPARStwo"})


class OmplPlanner(FreeSpacePlanner[OmplPlannerConfig]):
    """Any OMPL geometric planner over the costmap's free space."""

    Config = OmplPlannerConfig

    def __init__(self, config: OmplPlannerConfig) -> None:
        super().__init__(config)
        # Built once: each keeps its coarse graphs between plans on the same costmap.
        self._refiner = CostGridPlanner(
            CostGridConfig(clearance=config.clearance, cost_weight=config.cost_weight)
        )
        self._shortest = CostGridPlanner.shortest(config.clearance)

    def plan(self, costmap: Costmap, start: Pose2D, goal: Pose2D, seed: int = 0) -> PlannedPath:
        t0 = time.perf_counter()
        cfg = self.config
        space, s, g = self.free_space(costmap, start, goal)
        if space.segment_free(*s, *g):  # the straight line is free: nothing to sample
            pts = np.array([s, g], dtype=float)
        else:
            pts = _solve(space, s, g, cfg, seed, t0, self._shortest)
            if pts is None:
                raise PlanningError(
                    f"{cfg.planner} found no path from ({start.x:.2f}, {start.y:.2f}) "
                    f"to ({goal.x:.2f}, {goal.y:.2f}) within {cfg.iterations} iterations"
                    + (
                        ""
                        if time.perf_counter() - t0 < cfg.time_limit
                        else f" (stopped by the {cfg.time_limit:g} s watchdog)"
                    )
                )
        if cfg.refine:
            refined = self._refiner.refine(space, s, g, pts)
            if refined is not None:
                pts = refined
        return space.planned_path(pts, start, goal, t0)


_QUIETED = [False]


def _seed_ompl(seed: int) -> None:
    """Reseed OMPL's process-wide seed generator (see the module docstring).

    Also lowers OMPL's logging to warnings, once (its default prints Info lines for
    every plan); a level set by the application afterwards is left alone.
    """
    from ompl import util as ou

    if not _QUIETED[0]:
        ou.setLogLevel(ou.LOG_WARN)
        _QUIETED[0] = True
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)  # silences "Random number generation already started"
    try:
        ou.RNG.setSeed(int(seed) % 2_147_483_646 + 1)  # OMPL refuses 0
    finally:
        ou.setLogLevel(level)


def _path_ok(space: FreeSpace, pts: np.ndarray) -> bool:
    return all(space.segment_free(*pts[i], *pts[i + 1]) for i in range(len(pts) - 1))


def _solve(
    space: FreeSpace,
    start: tuple[float, float],
    goal: tuple[float, float],
    cfg: OmplPlannerConfig,
    seed: int,
    t0: float,
    shortest: CostGridPlanner,
) -> np.ndarray | None:
    """Local-frame waypoints from ``start`` to ``goal``, or None if none was found in time."""
    from ompl import base as ob
    from ompl import geometric as og

    anytime = cfg.planner in OPTIMIZING_PLANNERS
    threshold = -math.inf  # no threshold: nothing is short enough
    if anytime and cfg.cost_threshold is not None:
        ref = shortest.local_path(space, start, goal)
        if ref is None:
            return None  # not connected: no sampling planner will do better
        threshold = cfg.cost_threshold * path_length(ref)

    _seed_ompl(seed)  # before any OMPL object (and so any RNG) is created
    segment_free, point_free = space.segment_free, space.point_free

    class _SegmentValidator(ob.MotionValidator):
        def checkMotion(self, a, b) -> bool:  # noqa: N802 (OMPL's name)
            return segment_free(a[0], a[1], b[0], b[1])

    def is_valid(state) -> bool:
        return point_free(state[0], state[1])

    width, height = space.size
    ompl_space = ob.RealVectorStateSpace(2)
    bounds = ob.RealVectorBounds(2)
    bounds.setLow(0.0)
    bounds.setHigh(0, width)
    bounds.setHigh(1, height)
    ompl_space.setBounds(bounds)
    ss = og.SimpleSetup(ompl_space)
    ss.setStateValidityChecker(is_valid)
    si = ss.getSpaceInformation()
    validator = _SegmentValidator(si)
    si.setMotionValidator(validator)
    # Used for interpolation only (edges are checked exactly by the validator): ~ a cell.
    si.setStateValidityCheckingResolution(min(1.0, space.res / ompl_space.getMaximumExtent()))
    s_state, g_state = ompl_space.allocState(), ompl_space.allocState()
    s_state[0], s_state[1] = start
    g_state[0], g_state[1] = goal
    ss.setStartAndGoalStates(s_state, g_state)
    objective = ob.PathLengthOptimizationObjective(si)
    if not anytime:  # any path satisfies (else PRM grows its roadmap until the timeout)
        objective.setCostThreshold(ob.Cost(math.inf))
    elif threshold > 0.0:
        objective.setCostThreshold(ob.Cost(threshold))
    ss.setOptimizationObjective(objective)
    planner = getattr(og, cfg.planner)(si)
    if cfg.range is not None and hasattr(planner, "setRange"):
        planner.setRange(cfg.range)
    if cfg.goal_bias is not None and hasattr(planner, "setGoalBias"):
        planner.setGoalBias(cfg.goal_bias)
    ss.setPlanner(planner)
    ss.setup()  # only now: setup() without start and goal segfaults
    pdef = ss.getProblemDefinition()
    simplifier = og.PathSimplifier(si, pdef.getGoal(), objective) if cfg.simplify else None

    def current() -> tuple[np.ndarray, float]:
        """The planner's best solution, simplified on a copy: waypoints and length."""
        path = og.PathGeometric(pdef.getSolutionPath())
        raw = np.array([[st[0], st[1]] for st in path.getStates()], dtype=float)
        if simplifier is not None:
            simplifier.simplifyMax(path)  # bounded by work, not by time: deterministic
            pts = np.array([[st[0], st[1]] for st in path.getStates()], dtype=float)
            if not _path_ok(space, pts):  # never seen; the raw path is checked edge by edge
                pts = raw
        else:
            pts = raw
        del path
        return pts, float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))

    deadline = t0 + cfg.time_limit
    try:
        if anytime:
            return _run_rounds(ob, ss, pdef, current, cfg, threshold, deadline)
        if cfg.planner in THREADED_PLANNERS:  # the documented exception: the wall clock
            ss.solve(ob.timedPlannerTerminationCondition(max(deadline - time.perf_counter(), 1e-3)))
        else:
            ss.solve(ob.PlannerTerminationCondition(_IterationBudget(cfg.iterations, deadline)))
        return current()[0] if pdef.hasExactSolution() else None
    finally:  # nothing of OMPL's may outlive the plan (nanobind reports leaks at exit)
        simplifier = pdef = planner = objective = validator = si = ss = None
        s_state = g_state = bounds = ompl_space = None


class _IterationBudget:
    """A termination condition that counts its own evaluations (one per planner
    iteration) instead of reading the clock; the wall-clock ``deadline`` is a watchdog."""

    def __init__(self, iterations: int, deadline: float) -> None:
        self.left = iterations
        self.deadline = deadline

    def __call__(self) -> bool:
        self.left -= 1
        return self.left < 0 or time.perf_counter() >= self.deadline


def _run_rounds(ob, ss, pdef, current, cfg, threshold: float, deadline: float):
    """Run an anytime planner in doubling rounds until the path meets ``threshold`` or
    the iteration budget is spent (PRM-family planners: rounds of wall time)."""
    threaded = cfg.planner in THREADED_PLANNERS
    slice_s = cfg.time_limit / 32.0
    spent, limit = 0, cfg.round_iterations
    best_pts, best_len, last_raw = None, math.inf, math.inf
    while time.perf_counter() < deadline and (threaded or spent < cfg.iterations):
        if threaded:
            remaining = deadline - time.perf_counter()
            ss.solve(ob.timedPlannerTerminationCondition(min(slice_s, remaining)))
            slice_s *= 2.0
        else:
            budget = min(limit, cfg.iterations - spent)
            ss.solve(ob.PlannerTerminationCondition(_IterationBudget(budget, deadline)))
            spent += budget
            limit *= 2
        if not pdef.hasExactSolution():
            continue
        raw = pdef.getSolutionPath().length()
        if raw < last_raw:  # simplify only what changed
            last_raw = raw
            pts, length = current()
            if length < best_len:
                best_pts, best_len = pts, length
        if best_len <= threshold:  # (never, without a threshold: use the whole budget)
            break
    return best_pts
