"""Dispatchers: which robot gets a task that names none."""

from __future__ import annotations

import math
from collections.abc import Sequence

from agv_mission.fleet.base import (
    Assignment,
    DispatchError,
    FleetTask,
    RobotWork,
    TravelTime,
)
from agv_mission.fleet.configs import NearestIdleConfig, QuickestFinishConfig


def task_time(robot: RobotWork, task: FleetTask, travel_time: TravelTime) -> float:
    """Seconds ``robot`` needs for ``task`` once its held work is done: travel from where
    that work ends to the first goal, through the others in order, plus the task's work."""
    total, here = task.work_time, robot.end
    for goal in task.goals:
        total += travel_time(robot.name, here, goal)
        here = goal
    return total


def _require(task: FleetTask, robots: Sequence[RobotWork], bids: dict[str, float]) -> None:
    if not robots:
        raise DispatchError(f"task {task.id}: the fleet has no robots")
    if not any(math.isfinite(b) for b in bids.values()):
        raise DispatchError(
            f"task {task.id}: no available robot can reach its goals "
            f"({', '.join(r.name for r in robots)})"
        )


class QuickestFinishDispatcher:
    """Open-RMF's default bidding: every available robot bids the time it would finish
    the task, its held work first (``held_time`` + travel to and through the task's
    goals + the task's work); the lowest bid wins, ties to the robot listed first."""

    Config = QuickestFinishConfig

    def __init__(self, config: QuickestFinishConfig | None = None) -> None:
        self.config = config or QuickestFinishConfig()

    def assign(
        self, task: FleetTask, robots: Sequence[RobotWork], travel_time: TravelTime
    ) -> Assignment:
        bids = {
            r.name: (r.held_time + task_time(r, task, travel_time)) if r.available else math.inf
            for r in robots
        }
        _require(task, robots, bids)
        best = min(robots, key=lambda r: bids[r.name])  # min keeps the first of equals
        return Assignment(best.name, bids[best.name], bids)


class NearestIdleDispatcher:
    """The closest free vehicle: among idle robots, the one with the shortest travel to
    the task's first goal; when none is idle, the robot whose held work ends first (then
    the shortest travel). Ties go to the robot listed first."""

    Config = NearestIdleConfig

    def __init__(self, config: NearestIdleConfig | None = None) -> None:
        self.config = config or NearestIdleConfig()

    def assign(
        self, task: FleetTask, robots: Sequence[RobotWork], travel_time: TravelTime
    ) -> Assignment:
        first = task.goals[0] if task.goals else None
        keys: dict[str, tuple[float, float]] = {}
        bids: dict[str, float] = {}
        for r in robots:
            reach = travel_time(r.name, r.end, first) if first is not None else 0.0
            if not r.available or not math.isfinite(reach):
                keys[r.name] = (math.inf, math.inf)
                bids[r.name] = math.inf
                continue
            keys[r.name] = (0.0 if r.idle else r.held_time, reach)
            bids[r.name] = r.held_time + task_time(r, task, travel_time)
        _require(task, robots, bids)
        best = min(robots, key=lambda r: keys[r.name])
        return Assignment(best.name, bids[best.name], bids)
