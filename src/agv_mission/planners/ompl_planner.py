"""Global planning with OMPL's geometric planners (RRTConnect, BITstar, ... by name).

The robot is planned as a point in the plane (positions only: a differential drive
with a local MPC turns on the spot). The costmap reaches OMPL three ways, all OMPL's own:

* **Validity.** A state is valid when its cell's clearance exceeds ``robot_radius +
  clearance`` (lethal and inscribed cells never are). Edges are checked exactly by a
  vectorised :class:`ompl.base.MotionValidator` (every grid cell a segment passes through
  must be valid, i.e. a one-cell resolution), so no edge cuts a corner.
* **Objective.** :class:`CostmapObjective`, an :class:`ompl.base.OptimizationObjective`:
  a motion costs the integral of ``1 + cost_weight * cost / 252`` along it (the costmap's
  inflation cost, sampled every half cell; the same step cost ``cost_grid`` searches
  with), so optimising planners keep out of the inflation zone and to the middle of
  corridors, and ``cost_weight: 0`` is plain path length.
* **Simplification.** OMPL's :class:`ompl.geometric.PathSimplifier` over the same
  objective (shortcuts that make the cost worse are refused) smooths the solution.

Planning happens in the grid's own frame (see :class:`FreeSpace`); the callbacks capture
numpy data only, and every OMPL object lives and dies inside one plan.

What OMPL 2.0.1 (PyPI wheel, nanobind) does, as probed for this module:

* Planners. The wheel binds 14 geometric planners (:func:`configs.available_planners`);
  the library holds more (AITstar, ABITstar, EITstar, EST, TRRT, LazyPRM, SPARS, ...)
  but Python cannot construct them.
* Objectives. A Python subclass of ``OptimizationObjective`` has its ``motionCost``,
  ``stateCost`` and ``motionCostHeuristic`` called from C++; a subclass of
  ``StateCostIntegralObjective`` does not (its ``stateCost`` is never called), and one of
  ``PathLengthOptimizationObjective`` with its own ``motionCost`` crashes BITstar.
  ``costToGo`` cannot be overridden and ``setCostToGoHeuristic`` takes no Python
  function: informed samplers fall back to rejection sampling (OMPL warns; silenced).
  RRTConnect, RRT, the KPIECE family and AORRTC plan without the objective (they only
  look for a feasible, resp. shortest, path); the simplifier still applies it.
* Threads. ``SimpleSetup.solve`` keeps the GIL: a Python callback called from a
  planner's second thread deadlocks. PRM and PRMstar check for solutions on a second
  thread, which calls the termination condition and the objective: they get C++
  termination conditions on the wall clock and plan on path length
  (``PathLengthOptimizationObjective``); the simplifier, run afterwards on this thread,
  applies the costmap objective to their paths too. They are not reproducible.
* Seeding. ``ou.RNG.setSeed(s)`` can be called again after sampling has started: OMPL
  logs "Random number generation already started ..." (silenced here) but still reseeds
  the generator that seeds every RNG created afterwards. Each plan builds a fresh space,
  samplers, planner and simplifier right after reseeding, so a plan is a function of
  (costmap, start, goal, config, seed) for every single-threaded planner (not for plans
  run concurrently from several Python threads: the seed is process-global).
* Budgets (:mod:`ompl_budget`). A plan stops on a count, never on the clock: the
  termination condition counts its own evaluations (one per planner iteration) up to
  ``iterations``, so a run is byte-identical with or without other processes loading
  the CPU. The yardstick is the path ``cost_grid`` would plan (never the plan): a plan
  is good enough when it costs no more than ``cost_threshold`` times its cost under the
  same objective and is no longer than ``length_threshold`` times its length.
  Optimising planners run in doubling rounds (round k: ``round_iterations * 2**k``
  iterations, within the same total) until their simplified path is good enough (the
  objective carries the cost threshold, so a planner whose raw solution gets there
  stops inside a round). Planners that stop at their first solution (RRTConnect, ...)
  run again from scratch, up to ``restarts`` times, until one is: a first solution goes
  whichever way round the obstacles the trees met first (on the demo's pillars, twice
  the shortest), and no simplifier changes the way round. ``time_limit`` is only a
  watchdog, on the planning thread's CPU time: a loaded machine does not change a plan.
* Range. Planners that stop at their first solution get 0.5 m edges unless ``range``
  says otherwise: with OMPL's default (a fifth of the map's extent) a tree's first
  branches leap over a row of pillars and connect round the outside.
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
from agv_mission.planners.free_space import FreeSpace, FreeSpacePlanner, cost_factor
from agv_mission.planners.ompl_budget import (
    THREADED_PLANNERS,
    Yardstick,
    run_restarts,
    run_rounds,
    taut_length,
    watchdog_clock,
)
from agv_mission.planners.path_smoothing import path_length

# Anytime planners, worth running past their first solution: they improve it on the
# objective (AORRTC: on path length, which the simplifier then weighs by the objective).
OPTIMIZING_PLANNERS = frozenset(
    {"RRTstar", "InformedRRTstar", "SORRTstar", "BITstar", "PRMstar", "AORRTC"}
)
SAMPLES_PER_CELL = 2  # the cost integral samples a motion every half cell
VECTORISE_FROM = 24  # samples beyond which numpy beats a Python loop
COST_CACHE = 4  # cost-factor tables kept (one per costmap content and weight)
# The longest edge of planners that stop at their first solution (see OmplPlannerConfig.range).
FIRST_SOLUTION_RANGE = 0.5


def _pieces(length: float, piece: float) -> int:
    """How many equal pieces of at most ``piece`` metres ``length`` takes (1 when
    ``piece`` is not positive: no quick test applies)."""
    return max(1, math.ceil(length / piece)) if piece > 0.0 else 1


class CostIntegral:
    """The cost a motion pays over the costmap: the integral of ``1 + weight * cost / 252``
    (:func:`free_space.cost_factor`) along it, by the midpoint rule every half cell.

    Holds plain Python data only (a flat list of factors: scalar look-ups are what OMPL's
    per-edge callbacks need, and a list indexes faster than an array).
    """

    def __init__(
        self,
        space: FreeSpace,
        factor_array: np.ndarray,
        factors: list[float],
        distance: list[float],
    ) -> None:
        self.res, self.width, self.height = space.res, space.width, space.height
        self.factors, self.distance = factors, distance
        self.factor_array = factor_array
        self.comfort, self.required = space.comfort, space.required
        # How far from an obstacle the distance field is exact: the obstacle layer
        # recomputes it within the footprint plus inflation plus 0.5 m of its marks.
        self.exact_within = space.comfort + 0.5
        # The longest pieces :meth:`clear` can judge: longer motions are judged by pieces.
        self.cost_piece = 2.0 * (self.exact_within - self.comfort - 1.5 * self.res)
        self.free_piece = 2.0 * (self.exact_within - self.required - 1.5 * self.res)

    def _cell(self, px: float, py: float) -> int:
        """Flat index of the cell holding a local point (clamped to the grid)."""
        col = min(max(int(px / self.res), 0), self.width - 1)
        row = min(max(int(py / self.res), 0), self.height - 1)
        return row * self.width + col

    def clear(self, ax: float, ay: float, bx: float, by: float, length: float, d: float) -> bool:
        """A quick sufficient test that every cell the segment touches is farther than
        ``d`` from obstacles: its midpoint cell is farther than ``d`` plus half its length
        plus 1.5 cells (the distance field is 1-Lipschitz between cell centres; 1.5
        cells cover the rounding to cells), within the reach where the field is exact.
        False means "look closer", not "blocked"."""
        half = 0.5 * length + 1.5 * self.res
        if half > self.exact_within - d:
            return False
        return self.distance[self._cell(0.5 * (ax + bx), 0.5 * (ay + by))] - half > d

    def free(self, ax: float, ay: float, bx: float, by: float) -> bool | None:
        """True when the segment is quickly seen to be free for the robot (see
        :meth:`clear`), None when the exact check must decide."""
        w, h = self.width * self.res, self.height * self.res
        if not (0.0 <= ax < w and 0.0 <= bx < w and 0.0 <= ay < h and 0.0 <= by < h):
            return None
        length = math.hypot(bx - ax, by - ay)
        k = _pieces(length, self.free_piece)
        dx, dy, step = (bx - ax) / k, (by - ay) / k, length / k
        for i in range(k):
            x, y = ax + i * dx, ay + i * dy
            if not self.clear(x, y, x + dx, y + dy, step, self.required):
                return None
        return True

    def state(self, px: float, py: float) -> float:
        """The integrand at a local point."""
        return self.factors[self._cell(px, py)]

    def motion(self, ax: float, ay: float, bx: float, by: float) -> float:
        """The cost of the straight motion from ``a`` to ``b`` (local frame)."""
        length = math.hypot(bx - ax, by - ay)
        k = _pieces(length, self.cost_piece)
        dx, dy, step = (bx - ax) / k, (by - ay) / k, length / k
        for i in range(k):  # (a long motion piece by piece)
            x, y = ax + i * dx, ay + i * dy
            if not self.clear(x, y, x + dx, y + dy, step, self.comfort):
                break
        else:
            return length  # outside the inflation zone: the common case, and quick
        n = max(1, math.ceil(length * SAMPLES_PER_CELL / self.res))
        if n > VECTORISE_FROM:
            t = (np.arange(n) + 0.5) / n
            # (midpoints of a motion between states in bounds: never negative)
            cols = np.minimum(((ax + t * (bx - ax)) / self.res).astype(np.int64), self.width - 1)
            rows = np.minimum(((ay + t * (by - ay)) / self.res).astype(np.int64), self.height - 1)
            return float(self.factor_array[rows * self.width + cols].sum()) * length / n
        dx, dy = (bx - ax) / n, (by - ay) / n
        x, y = ax + 0.5 * dx, ay + 0.5 * dy
        inv, w, h, f = 1.0 / self.res, self.width - 1, self.height - 1, self.factors
        total = 0.0
        for _ in range(n):
            col, row = int(x * inv), int(y * inv)
            col = 0 if col < 0 else (w if col > w else col)
            row = 0 if row < 0 else (h if row > h else row)
            total += f[row * self.width + col]
            x += dx
            y += dy
        return total * length / n

    def path(self, pts: np.ndarray) -> float:
        """The cost of a polyline (local frame)."""
        return sum(
            self.motion(float(a[0]), float(a[1]), float(b[0]), float(b[1]))
            for a, b in zip(pts[:-1], pts[1:], strict=True)
        )


class OmplPlanner(FreeSpacePlanner[OmplPlannerConfig]):
    """Any OMPL geometric planner over the costmap's free space and inflation cost."""

    Config = OmplPlannerConfig

    def __init__(self, config: OmplPlannerConfig) -> None:
        super().__init__(config)
        # The yardstick of the cost threshold, built once: it keeps its coarse graphs.
        self._reference = CostGridPlanner(
            CostGridConfig(clearance=config.clearance, cost_weight=config.cost_weight)
        )
        self._tables: dict[tuple[int, int, int], tuple[np.ndarray, list[float], list[float]]] = {}
        self._last: dict[str, float] = {}

    def diagnostics(self) -> dict[str, float]:
        """Of the last plan: iterations used, whether it met the cost threshold, its cost
        and the reference cost (optimising planners), the cost after simplification."""
        return dict(self._last)

    def cost_integral(self, space: FreeSpace) -> CostIntegral:
        """The objective's cost over ``space``'s costmap (its factor table reused while the
        costmap's content is the same: the obstacle layer patches it in place)."""
        costmap = space.costmap
        key = (hash(costmap.cost.tobytes()), hash(costmap.distance.tobytes()), space.width)
        tables = self._tables.pop(key, None)
        if tables is None:
            factors = cost_factor(costmap.cost, self.config.cost_weight).ravel()
            tables = factors, factors.tolist(), costmap.distance.ravel().tolist()
        self._tables[key] = tables  # most recently used last
        while len(self._tables) > COST_CACHE:
            self._tables.pop(next(iter(self._tables)))
        return CostIntegral(space, *tables)

    def plan(self, costmap: Costmap, start: Pose2D, goal: Pose2D, seed: int = 0) -> PlannedPath:
        t0 = time.perf_counter()
        cfg = self.config
        clock = watchdog_clock(cfg.planner)
        watch0 = clock()
        space, s, g = self.free_space(costmap, start, goal)
        cost = self.cost_integral(space)
        self._last = {}
        if space.segment_free(*s, *g) and cost.motion(*s, *g) <= math.dist(s, g) * (1 + 1e-9):
            pts = np.array([s, g], dtype=float)  # free and outside the inflation zone: best
        else:
            pts = self._solve(space, cost, s, g, seed, watch0 + cfg.time_limit)
            if pts is None:
                raise PlanningError(
                    f"{cfg.planner} found no path from ({start.x:.2f}, {start.y:.2f}) "
                    f"to ({goal.x:.2f}, {goal.y:.2f}) within {cfg.iterations} iterations"
                    + (
                        ""
                        if clock() - watch0 < cfg.time_limit
                        else f" (stopped by the {cfg.time_limit:g} s watchdog)"
                    )
                )
        self._last["cost"] = round(cost.path(pts), 4)
        return space.planned_path(pts, start, goal, t0)

    def _solve(
        self,
        space: FreeSpace,
        cost: CostIntegral,
        start: tuple[float, float],
        goal: tuple[float, float],
        seed: int,
        deadline: float,
    ) -> np.ndarray | None:
        """Local-frame waypoints from ``start`` to ``goal``, or None if none was found
        (``deadline``: the watchdog's, on :func:`watchdog_clock`)."""
        cfg = self.config
        yardstick = Yardstick()  # none: nothing is good enough
        looks = cfg.planner in OPTIMIZING_PLANNERS or cfg.planner not in THREADED_PLANNERS
        if looks and cfg.cost_threshold is not None:  # (PRM alone plans once, on the clock)
            ref = self._reference.local_path(space, start, goal)
            if ref is None:
                return None  # not connected: no sampling planner will do better
            self._last["reference_cost"] = round(cost.path(ref), 4)
            self._last["reference_length"] = round(path_length(ref), 4)
            yardstick = Yardstick(
                cfg.cost_threshold * cost.path(ref), cfg.length_threshold * path_length(ref)
            )
        return _solve(space, cost, start, goal, cfg, seed, deadline, yardstick, self._last)


_QUIETED = [False]


def _seed_ompl(seed: int) -> None:
    """Reseed OMPL's process-wide seed generator (see the module docstring).

    Also lowers OMPL's logging to errors, once (its default prints Info lines for every
    plan, and informed planners warn that the objective has no cost-to-go heuristic,
    which the bindings cannot give it); a level set by the application afterwards is
    left alone.
    """
    from ompl import util as ou

    if not _QUIETED[0]:
        ou.setLogLevel(ou.LOG_ERROR)
        _QUIETED[0] = True
    level = ou.getLogLevel()
    ou.setLogLevel(ou.LOG_NONE)  # silences "Random number generation already started"
    try:
        ou.RNG.setSeed(int(seed) % 2_147_483_646 + 1)  # OMPL refuses 0
    finally:
        ou.setLogLevel(level)


def _path_ok(space: FreeSpace, pts: np.ndarray) -> bool:
    return all(space.segment_free(*pts[i], *pts[i + 1]) for i in range(len(pts) - 1))


def _objective_class(ob):
    """:class:`CostmapObjective`, built on first use (importing OMPL is slow)."""
    if "cls" not in _OBJECTIVE:

        class CostmapObjective(ob.OptimizationObjective):
            """Motion cost: the costmap's inflation cost integrated along the motion
            (:class:`CostIntegral`); its lower bound is the straight-line length."""

            def __init__(self, si, cost: CostIntegral) -> None:
                super().__init__(si)
                self.integral = cost
                self.setCostThreshold(ob.Cost(-math.inf))

            def stateCost(self, s):  # noqa: N802 (OMPL's name)
                return ob.Cost(self.integral.state(s[0], s[1]))

            def motionCost(self, a, b):  # noqa: N802
                return ob.Cost(self.integral.motion(a[0], a[1], b[0], b[1]))

            def motionCostHeuristic(self, a, b):  # noqa: N802
                return ob.Cost(math.hypot(b[0] - a[0], b[1] - a[1]))

        _OBJECTIVE["cls"] = CostmapObjective
    return _OBJECTIVE["cls"]


_OBJECTIVE: dict[str, type] = {}


def _solve(
    space: FreeSpace,
    cost: CostIntegral,
    start: tuple[float, float],
    goal: tuple[float, float],
    cfg: OmplPlannerConfig,
    seed: int,
    deadline: float,
    yardstick: Yardstick,
    report: dict[str, float],
) -> np.ndarray | None:
    """Set up, solve and simplify one OMPL problem (every OMPL object dies here)."""
    from ompl import base as ob
    from ompl import geometric as og

    anytime = cfg.planner in OPTIMIZING_PLANNERS
    threaded = cfg.planner in THREADED_PLANNERS
    _seed_ompl(seed)  # before any OMPL object (and so any RNG) is created
    segment_free, point_free, quick_free = space.segment_free, space.point_free, cost.free

    class _SegmentValidator(ob.MotionValidator):
        def checkMotion(self, a, b) -> bool:  # noqa: N802 (OMPL's name)
            ax, ay, bx, by = a[0], a[1], b[0], b[1]
            return quick_free(ax, ay, bx, by) or segment_free(ax, ay, bx, by)

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
    objective = _objective_class(ob)(si, cost)
    # PRM's solution thread would call back into Python: it gets OMPL's own path length.
    planner_objective = ob.PathLengthOptimizationObjective(si) if threaded else objective
    if not anytime:  # any path satisfies (else PRM grows its roadmap until the timeout)
        planner_objective.setCostThreshold(ob.Cost(math.inf))
    elif yardstick.cost > 0.0:
        planner_objective.setCostThreshold(ob.Cost(yardstick.cost))
    ss.setOptimizationObjective(planner_objective)
    planner = getattr(og, cfg.planner)(si)
    edge = cfg.range if cfg.range is not None or anytime else FIRST_SOLUTION_RANGE
    if edge is not None and hasattr(planner, "setRange"):
        planner.setRange(edge)
    if cfg.goal_bias is not None and hasattr(planner, "setGoalBias"):
        planner.setGoalBias(cfg.goal_bias)
    ss.setPlanner(planner)
    ss.setup()  # only now: setup() without start and goal segfaults
    pdef = ss.getProblemDefinition()
    simplifier = og.PathSimplifier(si, pdef.getGoal(), objective) if cfg.simplify else None

    def states(path) -> np.ndarray:
        return np.array([[st[0], st[1]] for st in path.getStates()], dtype=float)

    def simplified(path) -> tuple[np.ndarray, float]:
        """``path`` simplified in place, as waypoints with their cost; the raw waypoints
        when the simplifier made it worse (never seen; the raw path is checked edge by
        edge)."""
        raw = states(path)
        if simplifier is None:
            return raw, cost.path(raw)
        simplifier.simplifyMax(path)  # bounded by work, not by time: deterministic
        pts = states(path)
        if not _path_ok(space, pts) or cost.path(pts) > cost.path(raw):
            pts = raw
        return pts, cost.path(pts)

    def current() -> tuple[np.ndarray, float]:
        """The planner's best solution, simplified on a copy: waypoints and cost."""
        path = og.PathGeometric(pdef.getSolutionPath())
        try:
            return simplified(path)
        finally:
            del path

    def restarts() -> np.ndarray | None:
        """:func:`ompl_budget.run_restarts` with this problem's OMPL objects."""
        return run_restarts(
            ob, ss, pdef, lambda: og.PathGeometric(pdef.getSolutionPath()),
            lambda path: taut_length(space, states(path)),
            simplified, cfg, yardstick, deadline, report,
        )  # fmt: skip

    try:
        if anytime:
            return run_rounds(ob, ss, pdef, current, cfg, yardstick, deadline, report)
        if threaded:  # the documented exception: the wall clock
            remaining = max(deadline - watchdog_clock(cfg.planner)(), 1e-3)
            ss.solve(ob.timedPlannerTerminationCondition(remaining))
            return current()[0] if pdef.hasExactSolution() else None
        return restarts()
    finally:  # nothing of OMPL's may outlive the plan (nanobind reports leaks at exit)
        simplifier = pdef = planner = objective = planner_objective = validator = None
        si = ss = s_state = g_state = bounds = ompl_space = None
