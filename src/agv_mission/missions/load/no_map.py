"""``map: none``: a robot that knows nothing of the world (robots-and-worlds.md).

It localises by odometry (a mission that says nothing of localisation gets it, see
:func:`~agv_mission.missions.load.layout.default_to_odometry`; ``amcl``,
which needs a map to match scans against, is refused with that reason) and plans on a grid
where unknown space is free, as BARN's move_base does without a static map: the obstacle
layer marks and clears what the lidar shows. The grid covers the world's extent (a Gazebo
world's is its bodies' bounds plus 2 m), and the start and every pose the mission names
with :data:`NO_MAP_MARGIN` around each; a goal is checked only against it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import FREE, OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.maps.world_loader import DEFAULT_SCAN_HEIGHT
from agv_mission.maps.worlds import World
from agv_mission.missions.load.schema import Setup
from agv_mission.missions.load.world_checks import MAX_GRID_CELLS, NodeCheck, Report
from agv_mission.robots.robot_files import load_robot

NO_MAP_MARGIN = 2.0  # m around the world, the start and the goals


def scan_height(robot: str, base_dir: Path) -> float:
    """The scan height of the robot a mission names (where a Gazebo world is cut); the
    default when the robot cannot be read (its own check reports why)."""
    try:
        return float(load_robot(robot, base_dir).lidar.height)
    except Exception:  # noqa: BLE001 (the robot's own load names the problem)
        return DEFAULT_SCAN_HEIGHT


def check_localization(mission: Setup, report: Report) -> None:
    """``amcl`` refused on ``map: none``, with the reason."""
    if mission.stack.localization.type == "amcl":
        report(
            ("stack", "localization", "type"),
            "amcl localises by matching scans to a map, and `map: none` gives the robot "
            "none: use odometry",
        )


def no_map_grid(
    mission: Setup, world: World, rooms: dict[str, Room], nodes: Sequence[NodeCheck]
) -> OccupancyGrid:
    """The free grid a robot without a map plans on: the world's extent, and the start and
    every goal the mission's nodes and faults name with :data:`NO_MAP_MARGIN` around each.

    Raises ``ValueError`` when that grid would be too large for memory."""
    xmin, xmax, ymin, ymax = world.map.extent
    points: list[Pose2D] = []
    start = mission.start
    if start is None:
        points.append(world.spawn)
    elif isinstance(start, str):
        room = rooms.get(start)
        if room is not None and room.anchor is not None:
            points.append(room.anchor)
    else:
        points.append(start.to_pose2d())
    for _, ports, _ in nodes:
        points += [pose.to_pose2d() for _, pose in ports.goal_poses()]
    points += [f.pose.to_pose2d() for f in mission.faults if f.type == "kidnap"]
    for p in points:  # each with room around it; the world's extent as it is
        xmin, xmax = min(xmin, p.x - NO_MAP_MARGIN), max(xmax, p.x + NO_MAP_MARGIN)
        ymin, ymax = min(ymin, p.y - NO_MAP_MARGIN), max(ymax, p.y + NO_MAP_MARGIN)
    res = world.map.resolution
    width = math.ceil((xmax - xmin) / res - 1e-9)
    height = math.ceil((ymax - ymin) / res - 1e-9)
    if width * height > MAX_GRID_CELLS:
        raise ValueError(
            f"the grid around the world, the start and the goals would be {width * res:.0f} x "
            f"{height * res:.0f} m ({width * height:.3g} cells; at most {MAX_GRID_CELLS:.3g})"
        )
    data = np.full((height, width), FREE, dtype=np.int8)
    return OccupancyGrid(data, res, Pose2D(xmin, ymin, 0.0))
