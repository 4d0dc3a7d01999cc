"""Watching and steering a run: the hooks every front door uses.

An observer sees a run start, every control step (as a :class:`StepSample`) and the end;
a control is asked before every step and may pause, cancel, or set a remote command. The
runner builds samples only when at least one observer is attached, so a plain run pays
nothing for them.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.messages import LaserScan
from agv_mission.missions.schema import Mission
from agv_mission.robots.description import RobotDescription

if TYPE_CHECKING:
    from agv_mission.missions.runner import MissionRun, RunRecord

STATUS_NAMES = {
    Status.SUCCESS: "succeeded",
    Status.FAILURE: "failed",
    Status.RUNNING: "running",
    Status.INVALID: "not_run",
}


def status_name(status: Status) -> str:
    """A py_trees status as result.json spells task statuses."""
    return STATUS_NAMES.get(status, "not_run")


@dataclass(frozen=True)
class TreeNode:
    """One behaviour of the mission tree, as a viewer shows it."""

    name: str
    depth: int
    status: str  # SUCCESS | FAILURE | RUNNING | INVALID (py_trees' names, as the stream)


def tree_nodes(root: py_trees.behaviour.Behaviour) -> list[TreeNode]:
    """Every node under ``root`` (itself included), pre-order."""
    return [TreeNode(node.name, depth, node.status.value) for node, depth in _walk(root)]


def _walk(
    node: py_trees.behaviour.Behaviour, depth: int = 0
) -> Iterator[tuple[py_trees.behaviour.Behaviour, int]]:
    yield node, depth
    for child in node.children:
        yield from _walk(child, depth + 1)


@dataclass(frozen=True)
class RobotStart:
    """One robot of a run, as it starts."""

    name: str  # its ROS namespace in a fleet mission
    robot: RobotDescription
    start: Pose2D
    tree_nodes: list[TreeNode]  # pre-order
    keepout_mask: OccupancyGrid | None = None  # the keepout filter mask (100: kept out)
    speed_mask: OccupancyGrid | None = None  # the speed filter mask (% of max speed, 0: none)


@dataclass(frozen=True)
class RunStart:
    """What does not change during a run."""

    run_dir: Path | None
    mission: Mission  # the resolved mission model
    world_map: OccupancyGrid  # the known map (the mission's map:, else the world's)
    rooms: dict[str, Room]  # label -> Room (polygon, anchor)
    robots: list[RobotStart]  # every robot; a one-robot mission's one
    docks: dict[str, Dock] = field(default_factory=dict)  # chargers by name
    fleet: bool = False  # a fleet mission (robots: list): per-robot names are namespaces

    # A one-robot mission's robot (the first robot of a fleet).
    @property
    def robot(self) -> RobotDescription:
        return self.robots[0].robot

    @property
    def start(self) -> Pose2D:
        return self.robots[0].start

    @property
    def tree_nodes(self) -> list[TreeNode]:
        return self.robots[0].tree_nodes

    @property
    def keepout_mask(self) -> OccupancyGrid | None:
        return self.robots[0].keepout_mask

    @property
    def speed_mask(self) -> OccupancyGrid | None:
        return self.robots[0].speed_mask


@dataclass
class StepSample:
    """One control step (10 Hz of simulated time)."""

    t: float
    truth: Pose2D  # simulator's true pose (map frame)
    estimate: Pose2D  # localiser's estimate (map frame)
    covariance: np.ndarray | None  # 3x3 (x, y, yaw) of the estimate, when there is one
    odom: Pose2D  # dead-reckoned pose in the odom frame
    v: float  # command sent this step (after smoothing)
    w: float
    scan: LaserScan | None  # the newest lidar scan when one arrived this step
    scans: tuple[LaserScan, ...]  # every scan since the last step, oldest first (own stamps)
    particles: np.ndarray | None  # (n, 3) x, y, yaw when a particle filter updated this step
    plan: np.ndarray | None  # (k, 2+) a new global path made this step, else None
    horizon: np.ndarray | None  # (k, 2+) the local controller's predicted path, if any
    goal: Pose2D | None  # the current navigation goal
    grid: OccupancyGrid | None  # the map when it changed this step (growing SLAM map)
    events: list[dict[str, Any]]  # events appended this step (same dicts as result.json)
    tree_nodes: list[TreeNode] | None  # all nodes when any status changed this step
    task_index: int | None  # 0-based index of the running task
    task_type: str | None
    battery: float | None = None  # the level 0..1; None: not modelled
    charging: bool = False
    docked: str | None = None  # the dock the robot stands on
    robot: str = "robot"  # whose step this is (a fleet robot's name)
    # the people in the world, (ids, xy (n, 2), radii) of those present, in the samples of
    # the run's first robot (the world's, not any robot's view); None: a run without people
    people: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    # the IMU's samples since the last step (ImuSamples batches, oldest first); () without one
    imu: tuple[Any, ...] = ()


class RunObserver(Protocol):
    """Sees a run: its start, every control step, its record at the end (once)."""

    def on_start(self, start: RunStart) -> None: ...

    def on_step(self, sample: StepSample) -> None: ...

    def on_end(self, record: RunRecord) -> None: ...


class RunControl(Protocol):
    """Steers a run between control steps."""

    def before_step(self, run: MissionRun) -> None:
        """Called before every control step; may block (pause), may call
        ``run.cancel(reason)`` (the run ends ``aborted``), may set a robot's
        ``handle.remote_command = (v, w)`` for a teleop task (``run.handle``: the first
        robot's). A control class with ``only_cancels = True`` promises it never commands
        a robot, so a fleet's robots may decide in other processes (missions.team)."""
        ...
