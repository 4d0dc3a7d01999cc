"""The configuration blocks of the built-in planners (``stack.global_planner``,
``stack.local_planner``).

They live apart from the planners so that validating a mission or printing the schema
imports neither OMPL's planners nor casadi: each config names its plugin class by import
path (``plugin``), loaded only when a run builds it.
"""

from __future__ import annotations

import json
from functools import lru_cache
from importlib.util import find_spec
from pathlib import Path
from typing import ClassVar, Literal

from pydantic import Field, field_validator

from agv_mission.registry import PluginConfig
from agv_mission.stored import read_stored, store, stored_path


@lru_cache(maxsize=1)
def available_planners() -> tuple[str, ...]:
    """Names of the geometric planner classes this OMPL build provides: asked of OMPL once
    per build of its libraries and stored (loading them costs a ``validate`` ~0.1 s)."""
    build = _ompl_build()
    path = stored_path("ompl_planners", build, ".json")
    data = read_stored(path) if build else None
    try:
        names = json.loads(data) if data is not None else None
    except ValueError:
        names = None
    if isinstance(names, list) and names and all(isinstance(n, str) for n in names):
        return tuple(names)
    from ompl import base as ob
    from ompl import geometric as og

    found = sorted(
        name
        for name in dir(og)
        if isinstance(getattr(og, name), type) and issubclass(getattr(og, name), ob.Planner)
    )
    if build:
        store(path, json.dumps(found).encode())
    return tuple(found)


def _ompl_build() -> tuple[object, ...]:
    """What names this OMPL build: its shared libraries' paths, sizes and times (found
    without loading them); empty when there are none to name it (nothing is stored)."""
    spec = find_spec("ompl")
    if spec is None or not spec.submodule_search_locations:
        return ()
    files = []
    for folder in spec.submodule_search_locations:
        for lib in sorted(Path(folder).glob("*.so")):
            info = lib.stat()
            files.append((str(lib), info.st_size, info.st_mtime_ns))
    return tuple(files)


class OmplPlannerConfig(PluginConfig):
    """``global_planner`` block for OMPL (``type: ompl``)."""

    plugin: ClassVar[str] = "agv_mission.planners.ompl_planner:OmplPlanner"

    type: Literal["ompl"] = "ompl"
    planner: str = Field(
        "RRTConnect",
        description="OMPL geometric planner class, one the installed OMPL binds (OMPL 2.0.1: "
        "AORRTC, BFMT, BITstar, BKPIECE1, FMT, InformedRRTstar, KPIECE1, LBKPIECE1, PRM, "
        "PRMstar, RRT, RRTConnect, RRTstar, SORRTstar)",
    )
    iterations: int = Field(
        20000,
        ge=1,
        le=10_000_000,
        description="the budget of one plan: planner iterations (termination checks), "
        "counted, never timed, so a plan is the same under any CPU load",
    )
    time_limit: float = Field(
        5.0,
        gt=0,
        le=600.0,
        description="watchdog of one plan, CPU seconds of the planning thread (other "
        "processes and threads do not advance it): a plan still running then fails (and "
        "that run is not reproducible); PRM-family planners (which grow their roadmap in "
        "a second thread) run on the wall clock for this long",
    )
    simplify: bool = Field(
        True,
        description="OMPL's path simplifier (shortcuts, B-spline smoothing) over the same "
        "objective: no shortcut makes the cost worse (deterministic)",
    )
    cost_weight: float = Field(
        1.0,
        ge=0,
        le=100.0,
        description="the objective: a motion costs the integral of 1 + cost_weight * "
        "cost / 252 along it (the costmap's inflation cost, as cost_grid's step cost); "
        "0: path length",
    )
    clearance: float = Field(
        0.05, ge=0, le=5.0, description="metres of margin beyond the robot radius a path must keep"
    )
    range: float | None = Field(
        None,
        gt=0,
        le=1000.0,
        description="longest edge (metres) for planners that have one; None: 0.5 m for "
        "the planners that stop at their first solution (RRTConnect, RRT, ...: a few robot "
        "widths, so that their trees branch between obstacles as close as pillars and "
        "doors; OMPL's own, a fifth of the map's extent, 1.2 m on the tb3 arena, 5 m in the "
        "house, leaps over a row of pillars and connects round the outside), OMPL's own for "
        "the optimising ones (which converge slower with short edges)",
    )
    goal_bias: float | None = Field(
        None, ge=0, le=1, description="goal sampling probability where supported; None: OMPL's"
    )
    cost_threshold: float | None = Field(
        1.05,
        ge=1.0,
        le=100.0,
        description="planners stop once the path costs no more than this multiple of the "
        "cost (same objective) of the path cost_grid would plan, a yardstick only: optimising "
        "planners keep optimising, the others start afresh (up to ``restarts``); None: "
        "optimising planners use the whole iteration budget, the others run once",
    )
    length_threshold: float = Field(
        1.1,
        ge=1.0,
        le=100.0,
        description="with cost_threshold: the path must also be no longer than this "
        "multiple of the yardstick path's length (under the inflation cost a path that "
        "swings wide of every obstacle can cost less and be a fifth longer)",
    )
    restarts: int = Field(
        16,
        ge=1,
        le=10_000,
        description="planners that stop at their first solution (RRTConnect, RRT, the "
        "KPIECE family, ...): most solutions one plan may try, each a fresh run simplified, "
        "until one costs no more than cost_threshold times the yardstick (1: a single run)",
    )
    round_iterations: int = Field(
        200,
        ge=1,
        le=1_000_000,
        description="optimising planners: iterations of the first round (doubling)",
    )

    @field_validator("planner")
    @classmethod
    def _known_planner(cls, name: str) -> str:
        known = available_planners()
        if name not in known:
            raise ValueError(
                f"unknown planner {name!r}; OMPL geometric planners are: {', '.join(known)}"
            )
        return name


class CostGridConfig(PluginConfig):
    """``global_planner`` block of the default planner (``type: cost_grid``)."""

    plugin: ClassVar[str] = "agv_mission.planners.cost_grid:CostGridPlanner"

    type: Literal["cost_grid"] = "cost_grid"
    clearance: float = Field(
        0.05, ge=0, le=5.0, description="metres of margin beyond the robot radius a path must keep"
    )
    cost_weight: float = Field(
        1.0,
        ge=0,
        le=100.0,
        description="how much the inflation cost adds to a step (0: shortest path; 1: a "
        "step at the inscribed radius costs 2x, one outside the inflation zone 1x)",
    )
    coarse_resolution: float = Field(
        0.2, gt=0, le=2.0, description="block size of the coarse search, metres"
    )
    band: int = Field(
        2, ge=1, le=20, description="blocks either side of the coarse path the fine search may use"
    )
    max_turn_radius: float = Field(
        0.8, ge=0, le=10.0, description="largest fillet radius at a corner, metres (0: no fillets)"
    )
    min_turn_radius: float = Field(
        0.1, gt=0, le=10.0, description="corners that cannot take a fillet this large stay sharp"
    )
    max_detour: float | None = Field(
        1.05,
        ge=1.0,
        le=10.0,
        description="a plan longer than this multiple of the shortest path at the same "
        "clearance is searched again with less inflation cost; None: never",
    )
    keep_prior: float = Field(
        0.85,
        gt=0,
        le=1.0,
        description="replanning: the way of the previous path is kept (searched within "
        "``band`` blocks of it) unless it is blocked or another way is shorter than this "
        "share of it",
    )


class GridAstarConfig(PluginConfig):
    """``global_planner`` block for the grid planner (``type: grid_astar``)."""

    plugin: ClassVar[str] = "agv_mission.planners.grid_astar:GridAstarPlanner"

    type: Literal["grid_astar"] = "grid_astar"
    clearance: float = Field(
        0.05, ge=0, description="metres of margin beyond the robot radius a path must keep"
    )
    cost_weight: float = Field(
        1.0,
        ge=0,
        description="how much the inflation cost adds to a step (0: shortest path; "
        "1: a step next to the inscribed radius costs ~2x, mid-corridor ~1.1x)",
    )
    smooth: bool = Field(True, description="line-of-sight shortcuts that keep clearance")
    connectivity: Literal[8, 16] = Field(
        16,
        description="8: the 8 neighbours; 16: also knight moves, which cuts the grid's "
        "length distortion from 8 % to 3 % and so picks the truly shorter way round "
        "obstacles more often",
    )


class MpcWeights(PluginConfig):
    """Cost weights (per stage unless named terminal)."""

    position: float = Field(10.0, ge=0, description="squared distance to the reference point")
    heading: float = Field(0.5, ge=0, description="squared heading error to the path tangent")
    speed: float = Field(1.0, ge=0, description="squared error to the reference speed")
    angular_velocity: float = Field(0.05, ge=0, description="w^2")
    acceleration: float = Field(0.1, ge=0, description="a^2")
    angular_acceleration: float = Field(0.02, ge=0, description="alpha^2")
    terminal_position: float = Field(50.0, ge=0)
    terminal_heading: float = Field(0.5, ge=0)
    slack_linear: float = Field(20.0, ge=0, description="exact-penalty weight of the slack")
    slack_quadratic: float = Field(1e4, ge=0)


class SolverOptions(PluginConfig):
    """Interior-point settings (used by fatrop and ipopt alike)."""

    max_iter: int = Field(40, ge=1)
    tol: float = Field(1e-3, gt=0)
    mu_init: float = Field(1e-3, gt=0, description="small: the warm start is close to optimal")


class MpcConfig(PluginConfig):
    plugin: ClassVar[str] = "agv_mission.planners.mpc:MpcController"

    type: Literal["mpc"] = "mpc"
    horizon: int = Field(20, ge=2, le=100, description="number of model steps N")
    dt: float = Field(0.1, gt=0, description="model step, s")
    max_obstacles: int = Field(
        256,
        ge=0,
        description="lidar points considered (the nearest to the robot); 0: no obstacle "
        "constraints",
    )
    obstacles_per_stage: int = Field(
        2,
        ge=1,
        description="constraints per model step: the points nearest that step's predicted "
        "position (a few per step instead of every point at every step keeps the solve small)",
    )
    obstacle_range: float = Field(
        1.0, gt=0, description="points farther than this from a predicted position are ignored, m"
    )
    safety_margin: float = Field(0.05, ge=0, description="clearance beyond robot_radius, m")
    people_margin: float = Field(
        0.2,
        ge=0,
        description="more room kept from a person's body than from a wall, m (people move "
        "unpredictably within the horizon: the constant-velocity guess is only a guess; "
        "among people walking both ways in a 2.2 m aisle 0.2 m kept 0.30 m and never stood, "
        "where 0.3 m stood 7 % of the time)",
    )
    solver: Literal["rti", "fatrop", "ipopt"] = Field(
        "rti",
        description="rti: one Gauss-Newton SQP step per control step (real-time iteration, "
        "a dense QP on the controls solved by DAQP); fatrop / ipopt: the NLP solved to "
        "tolerance every step",
    )
    rti_cold_iterations: int = Field(
        3, ge=1, description="rti: SQP steps when there is no previous solution to start from"
    )
    solver_options: SolverOptions = Field(default_factory=SolverOptions)
    weights: MpcWeights = Field(default_factory=MpcWeights)
    decel_fraction: float = Field(
        0.5, gt=0, le=1, description="reference braking = this x max_acc_v (margin for tracking)"
    )
    turn_fraction: float = Field(0.7, gt=0, le=1, description="reference turn rate <= this x max_w")
    goal_tolerance: float = Field(0.01, gt=0, description="closer than this: just brake, m")
    rotate_threshold: float = Field(
        1.2, gt=0, description="heading error to the path (rad) above which it turns in place"
    )
    rotate_exit: float = Field(0.3, gt=0, description="heading error to leave turn-in-place")
    rotate_speed_weight: float = Field(
        100.0, gt=0, description="speed-weight multiplier while turning in place"
    )
    lookahead: float = Field(0.3, gt=0, description="path point the heading error is taken to, m")
    final_approach: float = Field(
        0.15, gt=0, description="closer to the goal: heading weight fades, turn towards the goal"
    )
    final_position_gain: float = Field(
        100.0, ge=1, description="max position-weight gain on the final approach (1/d^2 law)"
    )
    final_rotate_threshold: float = Field(
        2.0, gt=0, description="turn-in-place threshold on the final approach, rad"
    )
    overshoot_tolerance: float = Field(
        0.02, ge=0, description="goal behind the robot and closer than this: stop, m"
    )


class PurePursuitConfig(PluginConfig):
    plugin: ClassVar[str] = "agv_mission.planners.pure_pursuit:PurePursuitController"

    type: Literal["pure_pursuit"] = "pure_pursuit"
    lookahead: float = Field(0.3, gt=0, description="lookahead distance along the path, m")
    speed: float | None = Field(None, gt=0, description="cruise speed, m/s (None: max_v)")
    goal_slowdown_distance: float = Field(
        0.3, ge=0, description="speed scales down linearly over this distance to the goal, m"
    )
    min_speed: float = Field(0.03, gt=0, description="creep speed for the last centimetres, m/s")
    decel_fraction: float = Field(0.5, gt=0, le=1, description="braking = this x max_acc_v")
    turn_fraction: float = Field(0.7, gt=0, le=1, description="path turn rate <= this x max_w")
    goal_tolerance: float = Field(0.01, gt=0, description="closer than this: brake, m")
    overshoot_tolerance: float = Field(
        0.02, ge=0, description="goal behind the robot and closer than this: stop, m"
    )
    rotate_threshold: float = Field(
        0.9, gt=0, description="heading error (rad) to the lookahead point to turn in place"
    )
    rotate_exit: float = Field(0.25, gt=0, description="heading error to leave turn-in-place")
    rotate_gain: float = Field(2.0, gt=0, description="w = gain x heading error when turning")


def goal_margin(planner_config: PluginConfig) -> float:
    """Metres beyond the robot's radius that a goal (and every path) must keep from
    obstacles: the global planner's ``clearance``. ``validate`` checks goals with the same
    margin the navigator plans with, so a goal that passes validation can be planned to."""
    return float(getattr(planner_config, "clearance", 0.0))
