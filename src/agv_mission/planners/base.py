"""What every planner plugin speaks: paths, commands and their failures."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap


class PlanningError(RuntimeError):
    """The global planner found no path; the message says why."""


@dataclass
class PlannedPath:
    """A global path in the map frame: (N, 2) waypoints from start to goal."""

    points: np.ndarray
    planning_time: float = 0.0  # wall seconds spent, for benchmarks only

    @property
    def length(self) -> float:
        if len(self.points) < 2:
            return 0.0
        return float(np.sum(np.linalg.norm(np.diff(self.points, axis=0), axis=1)))


@dataclass(frozen=True)
class VelocityLimits:
    """Bounds a local planner must keep (from the robot description)."""

    max_v: float
    max_w: float
    max_acc_v: float
    max_acc_w: float
    min_v: float = 0.0  # reversing is not allowed unless a plugin says otherwise


@dataclass
class VelocityCommand:
    """A ``cmd_vel``: linear and angular velocity, plus solver diagnostics."""

    v: float
    w: float
    ok: bool = True
    solve_time: float = 0.0  # wall seconds, for benchmarks only
    predicted: np.ndarray | None = None  # (N, 2) predicted positions, for plots


class GlobalPlanner(Protocol):
    """Plans a path on a costmap. Built as ``cls(config)``."""

    @property
    def clearance(self) -> float:
        """Metres of margin beyond the robot's radius that every path keeps."""
        ...

    def plan(self, costmap: Costmap, start: Pose2D, goal: Pose2D, seed: int = 0) -> PlannedPath:
        """A free path from ``start`` to ``goal``; raises :class:`PlanningError` if none."""
        ...

    def diagnostics(self) -> dict[str, float]:
        """Counters a run may report (may be empty)."""
        ...


class LocalPlanner(Protocol):
    """Follows a path one control step at a time. Built as ``cls(config, limits=...,
    robot_radius=..., control_period=...)``."""

    def reset(self) -> None:
        """Forget the previous goal (warm starts, progress)."""
        ...

    def compute(
        self,
        pose: Pose2D,
        velocity: tuple[float, float],
        path: np.ndarray,
        goal: Pose2D,
        obstacles: np.ndarray,
        moving: np.ndarray | None = None,
    ) -> VelocityCommand:
        """The command for this step towards ``goal`` along ``path``; ``moving``: tracked
        moving obstacles (people), rows (x, y, radius, vx, vy), for a planner that predicts
        them (one that does not gets their points among ``obstacles``)."""
        ...

    def diagnostics(self) -> dict[str, float]:
        """Counters a run may report (may be empty)."""
        ...
