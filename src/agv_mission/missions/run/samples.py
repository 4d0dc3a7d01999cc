"""What one robot's control step looked like: the :class:`StepSample` observers see, the
:class:`RobotReport` the rest of the run reads, and the tree's nodes as a viewer shows
them. Plain data, below the loop that makes it and the hooks that hand it on."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.sensor_msgs import LaserScan

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


@dataclass(frozen=True)
class RobotReport:
    """A robot's step as the rest of the run reads it: its command, estimate, outcome,
    the wall it touched, and what the fleet layer reserves for it."""

    command: tuple[float, float]
    estimate: Pose2D
    status: str | None
    reason: str | None
    new_collision: dict[str, float] | None
    yielding: bool
    navigating: bool
    traffic_path: np.ndarray | None
