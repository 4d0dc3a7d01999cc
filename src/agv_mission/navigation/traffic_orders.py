"""How a navigator obeys the fleet's traffic layer (a narrow interface: any object with
``action``, ``limit``, ``detour`` and ``avoid``, handed over every control step before the
tree ticks): ``wait`` stops it (keeping the plan, no 'no progress' recovery), ``go`` with a
``limit`` slows it so it can stop within that many metres, ``yield`` drives it to the
detour pose and holds it there until released (then it replans to its goal), ``replan``
plans again with the ``avoid`` points as lethal cells.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.navigation.state import RobotState
from agv_mission.planners.base import PlannedPath, PlanningError, VelocityCommand


class TrafficOrder(Protocol):
    """What the navigator reads of a traffic decision (``fleet.base.TrafficDecision``)."""

    action: str  # go | wait | yield | replan
    limit: float | None  # metres the robot may still advance along its path
    detour: Pose2D | None  # where to step aside (yield)
    avoid: np.ndarray | None  # (k, 2) points to plan round (replan)


#: Metres a robot stops short of the limit it was given (its estimate's jitter).
LIMIT_SLACK = 0.02


class ObeysTraffic:
    """The navigator's side of the traffic layer: this step's order, the detour it drives
    to, and the other robots' bodies (:class:`~agv_mission.navigation.navigator.Navigator`
    holds the rest: its goal, plan, planners and costmap)."""

    order: TrafficOrder | None
    detour: Pose2D | None
    detour_path: PlannedPath | None
    fleet_bodies: np.ndarray
    running: bool  # driving to a goal (the navigator's status)

    def obey(self, order: TrafficOrder | None, state: RobotState) -> None:
        """Take this step's traffic decision (before the behaviour tree ticks)."""
        self.order = order
        action = order.action if order is not None else "go"
        if action == "yield" and order is not None and order.detour is not None:
            if self.detour != order.detour:
                self.detour = order.detour
                self.detour_path = self._plan_to(state.estimate, order.detour, None)
            return
        if self.detour is not None:  # released: back to the goal, if there is one
            self.detour = self.detour_path = None
            if self.running and self.goal is not None:
                self._last_progress_time = state.time
                self.path = None
                self._plan(state)
        if action == "replan" and order is not None and self.running:
            self._plan_around(state, order.avoid)

    @property
    def yielding(self) -> bool:
        return self.detour is not None

    def traffic_path(self) -> np.ndarray | None:
        """The path the robot is driving now (to its goal, or to a detour), None when it
        drives none: what the traffic layer reserves."""
        if self.detour is not None:
            return None if self.detour_path is None else self.detour_path.points
        if self.running and self.path is not None:
            return self.path.points
        return None

    def _plan_to(self, start: Pose2D, goal: Pose2D, avoid: np.ndarray | None) -> PlannedPath | None:
        """A plan on the costmap (with ``avoid`` points lethal), None when there is none."""
        costmap = self.costmap
        if avoid is not None and len(avoid):
            marks = np.zeros(costmap.grid.data.shape, dtype=bool)
            rows, cols = costmap.grid.world_to_cell(np.asarray(avoid, dtype=float))
            inside = costmap.grid.in_bounds(rows, cols)
            marks[rows[inside], cols[inside]] = True
            costmap = costmap.with_obstacles(marks)
        seed = self.seed + self.stats.plans
        self.stats.plans += 1
        try:
            path = self.global_planner.plan(costmap, start, goal, seed=seed)
        except PlanningError:
            return None
        self.paths.append(path.points.copy())
        self.stats.planning_times.append(path.planning_time)
        return path

    def _plan_around(self, state: RobotState, avoid: np.ndarray | None) -> None:
        """Replan to the goal round the others' reserved space; keep the plan if there is
        no way round (the traffic layer then asks the other robot to make way)."""
        assert self.goal is not None
        path = self._plan_to(state.estimate, self.goal, avoid)
        if path is not None:
            self.path = path
            self.stats.replans += 1
            self._last_progress_time = state.time

    def _limited(self, cmd: VelocityCommand) -> VelocityCommand:
        """The command slowed so the robot can stop within the traffic limit."""
        order = self.order
        if order is None or order.limit is None or order.action not in ("go", "yield"):
            return cmd
        # one control period at v, then braking at the acceleration limit: v dt + v^2 / 2a
        room = max(order.limit - LIMIT_SLACK, 0.0)
        a, dt = self.limits.max_acc_v, self.control_period
        cap = a * (math.sqrt(dt * dt + 2.0 * room / a) - dt)
        if abs(cmd.v) > cap:
            cmd = replace(cmd, v=math.copysign(cap, cmd.v))
        return cmd

    def _drive_detour(self, state: RobotState) -> VelocityCommand:
        """Towards the detour pose, then stand there until released."""
        assert self.detour is not None
        self._last_progress_time = state.time
        pose = state.estimate
        if self.detour_path is None or pose.distance_to(self.detour) <= self._xy_tol:
            return VelocityCommand(0.0, 0.0)
        cmd = self.local_planner.compute(
            pose, state.velocity, self.detour_path.points, self.detour, self._near(state)
        )
        self.horizon = cmd.predicted
        return self._limited(cmd)
