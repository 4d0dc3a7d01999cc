"""How long an OMPL plan plans, and when it has planned enough.

A plan stops on a count, never on the clock (:class:`IterationBudget`), so it is the same
under any CPU load; its watchdog reads the planning thread's CPU time
(:func:`watchdog_clock`), which other processes and threads do not advance; it stops early once its path meets a :class:`Yardstick` (the cost and
length of the path ``cost_grid`` would plan, times a threshold). Anytime planners run in
doubling rounds (:func:`run_rounds`); planners that stop at their first solution run
again from scratch (:func:`run_restarts`). The OMPL objects are the caller's
(:mod:`ompl_planner`): these loops only call ``solve``, ``clear`` and the callbacks given.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from agv_mission.planners.configs import OmplPlannerConfig
from agv_mission.planners.free_space import FreeSpace
from agv_mission.planners.path_smoothing import any_angle, path_length

# Planners that evaluate the termination condition and the objective from a second thread.
THREADED_PLANNERS = frozenset({"PRM", "PRMstar"})
TAUT_STEP_CELLS = 4  # a raw path's way round is pulled taut through points 4 cells apart


@dataclass(frozen=True)
class Yardstick:
    """When a plan is good enough to stop planning: it costs no more than ``cost`` and is
    no longer than ``length`` (``cost_threshold`` and ``length_threshold`` times those of
    the path cost_grid would plan; -inf: never good enough). The length matters as much
    as the cost: under the inflation cost a path that swings wide of every pillar can
    cost less than the yardstick and still be a fifth longer."""

    cost: float = -math.inf
    length: float = -math.inf

    @property
    def given(self) -> bool:
        return self.cost > -math.inf

    def met(self, pts: np.ndarray, cost: float) -> bool:
        return cost <= self.cost and path_length(pts) <= self.length


def taut_length(space: FreeSpace, pts: np.ndarray) -> float:
    """The length of ``pts``'s way round obstacles: the path, a point every
    ``TAUT_STEP``, pulled taut by line of sight through free cells (to within a few
    per cent: enough to tell one way round an obstacle from another)."""
    step = TAUT_STEP_CELLS * space.res
    steps = np.maximum(np.ceil(np.linalg.norm(np.diff(pts, axis=0), axis=1) / step), 1)
    dense = np.concatenate(
        [
            a + (np.arange(k)[:, None] / k) * (b - a)
            for a, b, k in zip(pts[:-1], pts[1:], steps, strict=True)
        ]
        + [pts[-1:]]
    )
    floor = np.full(len(dense) - 1, space.required + space.res)  # any free segment will do
    return path_length(any_angle(space, dense, floor, space.comfort))


def watchdog_clock(planner: str) -> Callable[[], float]:
    """The clock of a plan's watchdog: the planning thread's CPU seconds, so a loaded
    machine (other processes, a thread holding the interpreter) does not cut a plan short
    and change the run; wall seconds for the planners that plan from threads of their own
    (PRM, PRMstar: they stop on the clock anyway)."""
    return time.perf_counter if planner in THREADED_PLANNERS else time.thread_time


class IterationBudget:
    """A termination condition that counts its own evaluations (one per planner
    iteration) instead of reading the clock; ``deadline`` on ``clock`` is a watchdog."""

    def __init__(self, iterations: int, deadline: float, clock: Callable[[], float]) -> None:
        self.left = iterations
        self.deadline = deadline
        self.clock = clock

    def __call__(self) -> bool:
        self.left -= 1
        return self.left < 0 or self.clock() >= self.deadline


def run_restarts(
    ob,
    ss,
    pdef,
    solution: Callable[[], object],
    taut_length: Callable[[object], float],
    simplified: Callable[[object], tuple[np.ndarray, float]],
    cfg: OmplPlannerConfig,
    yardstick: Yardstick,
    deadline: float,
    report: dict[str, float],
) -> np.ndarray | None:
    """Run a planner that stops at its first solution (RRTConnect, RRT, the KPIECE
    family, ...) again from scratch until a solution meets the ``yardstick`` or
    ``cfg.restarts`` solutions or the iteration budget are spent, and keep the best (the
    cheapest of those that meet it, else the cheapest): what OMPL's AnytimePathShortening
    does with its planner instances, which the Python bindings do not expose.

    A single run returns whichever way round the obstacles its trees happened to meet
    first: on the demo map a path round the outside of the pillars, twice the length of
    the way between them. The simplifier cannot change that way round; a fresh run can.
    A solution whose way round is longer than the yardstick's length (the raw path
    pulled taut by line of sight, ``taut_length``: milliseconds, where OMPL's simplifier
    in Python callbacks takes a tenth of a second) is not simplified; the others are, by
    OMPL's simplifier in full, and judged as simplified.
    """
    clock = watchdog_clock(cfg.planner)
    spent, solutions = 0, 0
    best_pts, best = None, (True, math.inf)  # (misses the yardstick, cost)
    fallback, fallback_way = None, math.inf  # the shortest way round, not yet simplified
    while clock() < deadline and spent < cfg.iterations:
        if solutions:
            ss.clear()  # the planner's trees and the solution; start and goal stay
        budget = IterationBudget(cfg.iterations - spent, deadline, clock)
        ss.solve(ob.PlannerTerminationCondition(budget))
        spent += max(1, cfg.iterations - spent - max(budget.left, 0))
        if not pdef.hasExactSolution():
            break  # the whole remaining budget found nothing: another run would not
        solutions += 1
        path = solution()
        way = taut_length(path)
        if yardstick.given and way > yardstick.length:  # the long way round
            if way < fallback_way:
                fallback, fallback_way = path, way
        else:
            pts, path_cost = simplified(path)
            report["simplified"] = report.get("simplified", 0.0) + 1.0
            key = (not yardstick.met(pts, path_cost), path_cost)
            if key < best:
                best_pts, best = pts, key
        del path
        if not best[0] or solutions >= cfg.restarts or not yardstick.given:
            break  # (no yardstick: one run, as OMPL's planner alone)
    if best_pts is None and fallback is not None:
        best_pts, path_cost = simplified(fallback)
        best = (not yardstick.met(best_pts, path_cost), path_cost)
    fallback = None
    report["iterations"] = float(spent)
    report["solutions"] = float(solutions)
    if yardstick.given:
        report["met_threshold"] = float(not best[0])
    return best_pts


def run_rounds(
    ob,
    ss,
    pdef,
    current: Callable[[], tuple[np.ndarray, float]],
    cfg: OmplPlannerConfig,
    yardstick: Yardstick,
    deadline: float,
    report: dict[str, float],
) -> np.ndarray | None:
    """Run an anytime planner in doubling rounds until the simplified path meets the
    ``yardstick`` or the iteration budget is spent (PRMstar: rounds of wall time)."""
    threaded = cfg.planner in THREADED_PLANNERS
    clock = watchdog_clock(cfg.planner)
    slice_s = cfg.time_limit / 32.0
    spent, limit = 0, cfg.round_iterations
    best_pts, best, last_raw = None, (True, math.inf), math.inf
    while clock() < deadline and (threaded or spent < cfg.iterations):
        if threaded:
            remaining = deadline - clock()
            ss.solve(ob.timedPlannerTerminationCondition(min(slice_s, remaining)))
            slice_s *= 2.0
        else:
            budget = IterationBudget(min(limit, cfg.iterations - spent), deadline, clock)
            ss.solve(ob.PlannerTerminationCondition(budget))
            spent += max(1, min(limit, cfg.iterations - spent) - max(budget.left, 0))
            limit *= 2
        if not pdef.hasExactSolution():
            continue
        raw = pdef.getSolutionPath().length()
        if raw != last_raw:  # simplify only what changed
            last_raw = raw
            pts, path_cost = current()
            key = (not yardstick.met(pts, path_cost), path_cost)
            if key < best:
                best_pts, best = pts, key
        if not best[0]:  # (never, without a yardstick: use the whole budget)
            break
    report["iterations"] = float(spent)
    report["met_threshold"] = float(not best[0])
    return best_pts
