"""A fleet's tasks released when the run starts, in their order: one that names its robot
queues on it (work the robot then holds); one that names none goes to the robot the
``dispatcher`` picks. A robot bids with the work it holds: its own goals (from where it
starts), then the tasks already queued on it, travelled at its top speed over its free
space (:class:`~agv_mission.fleet.travel.GridTravelTime`)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from agv_mission.fleet.base import FleetTask, RobotWork
from agv_mission.fleet.travel import GridTravelTime
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.registry import PluginConfig, registry


@dataclass(frozen=True)
class Bidder:
    """A robot as the dispatch sees it: its start, the goals of its own work, and the
    costmap and top speed its travel times come from."""

    name: str
    start: Pose2D
    goals: Sequence[Pose2D]
    costmap: Costmap
    speed: float


@dataclass(frozen=True)
class Release:
    """One of the fleet's tasks: its place in ``tasks:`` (0-based), the poses it drives
    to, and the robot it names (None: the dispatcher decides)."""

    index: int
    goals: Sequence[Pose2D]
    robot: str | None = None


@dataclass(frozen=True)
class Queued:
    """Where a released task went: its robot; for a dispatched one, when the robot would
    be done (seconds from now)."""

    robot: str
    finish: float | None = None  # None: the task named its robot


def release_tasks(
    dispatcher: PluginConfig, robots: Sequence[Bidder], tasks: Sequence[Release]
) -> list[Queued]:
    """Where each of ``tasks`` goes, in their order (the ``dispatcher`` slot's plugin
    picks for a task that names no robot)."""
    travel = {r.name: GridTravelTime(r.costmap, r.speed) for r in robots}

    def travel_time(name: str, a: Pose2D, b: Pose2D) -> float:
        return travel[name](a, b)

    def held(name: str, start: Pose2D, goals: Sequence[Pose2D], already: float) -> RobotWork:
        here, total = start, already
        for goal in goals:
            total += travel_time(name, here, goal)
            here = goal
        return RobotWork(name, here, total if np.isfinite(total) else already)

    work = {r.name: held(r.name, r.start, r.goals, 0.0) for r in robots}
    picker = registry.create("dispatcher", dispatcher)
    out = []
    for task in tasks:
        if task.robot is not None:  # assigned: work its robot holds from now on
            w = work[task.robot]
            work[task.robot] = held(task.robot, w.end, task.goals, w.held_time)
            out.append(Queued(task.robot))
            continue
        goals = tuple(task.goals)
        got = picker.assign(FleetTask(str(task.index), goals), list(work.values()), travel_time)
        end = goals[-1] if goals else work[got.robot].end
        work[got.robot] = RobotWork(got.robot, end, got.finish)
        out.append(Queued(got.robot, got.finish))
    return out
