"""A validated mission against its world, before anything runs: the start pose, goals,
waypoints and kidnap poses on the map and clear of obstacles, unmapped obstacles clear of
the start, ``map_area`` bounds on the map, and a reachable goal in every room visited.

Each check reports through ``report(field_path, message)`` and goes on, so one run of
``validate`` names every problem.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from agv_mission.behaviors.ports import NodePorts
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.docks import Dock, dock_problem
from agv_mission.maps.grid import UNKNOWN, OccupancyGrid
from agv_mission.maps.rooms import Room, reachable_cells, room_point
from agv_mission.maps.worlds import Box, Cylinder, World
from agv_mission.missions.load.schema import Setup
from agv_mission.missions.load.yaml_lines import FieldPath
from agv_mission.planners.configs import goal_margin
from agv_mission.robots.description import RobotDescription

MAX_GRID_CELLS = 16_000_000  # a costmap or SLAM grid: 16 M cells (e.g. 200 m x 200 m at 5 cm)

START_MARGIN = 0.1  # m beyond the robot's radius: a room's start point, like its visit goal

Report = Callable[[FieldPath, str], None]
#: A node of the mission's tree: its field path, its ports, and where to report.
NodeCheck = tuple[FieldPath, NodePorts, Report]


@dataclass
class Placement:
    """Where a mission stands in its world once the checks passed."""

    world: World  # with the mission's unmapped obstacles in its geometry
    start: Pose2D
    room_goals: dict[str, Pose2D]  # where each visited room is entered


def costmap_fits(mission: Setup, grid: OccupancyGrid, report: Report) -> bool:
    """The costmap of ``grid`` (the robot's map) at ``stack.costmap.resolution`` fits in
    memory (checked before it is built)."""
    resolution = mission.stack.costmap.resolution
    if resolution is None:
        return True
    cells = grid_cells(grid.extent, resolution)
    if cells > MAX_GRID_CELLS:
        report(
            ("stack", "costmap", "resolution"),
            f"{resolution:g} m cells make a costmap of {cells:.3g} cells for this world; "
            f"at most {MAX_GRID_CELLS:.3g} (use a coarser resolution)",
        )
        return False
    return True


def place_mission(
    mission: Setup,
    world: World,
    robot: RobotDescription,
    rooms: dict[str, Room],
    costmap: Costmap,
    report: Report,
    nodes: Sequence[NodeCheck] = (),
) -> Placement:
    """Every pose and area the mission (and each node of its tree) names, checked
    against the world's map."""
    start = start_pose(mission, world, rooms, costmap, report)
    _check_pose(start, costmap, ("start",), report)
    margin = goal_margin(mission.stack.global_planner)  # goals: as the navigator plans
    for path, ports, node_report in nodes:
        for sub, pose in ports.goal_poses():
            _check_pose(pose.to_pose2d(), costmap, path + sub, node_report, margin)
    for i, fault in enumerate(mission.faults):
        if fault.type == "kidnap":
            _check_pose(fault.pose.to_pose2d(), costmap, ("faults", i, "pose"), report)
    if mission.obstacles:
        world = _with_obstacles(world, mission.obstacles)
        for i, obstacle in enumerate(mission.obstacles):
            gap = _distance_to_obstacle(obstacle, start.x, start.y)
            if gap < robot.footprint_radius:
                report(
                    ("obstacles", i),
                    f"the robot's start ({start.x:g}, {start.y:g}) "
                    f"lies within {robot.footprint_radius:g} m of this obstacle",
                )
    _check_map_areas(mission, world.map.extent, nodes)
    room_goals = _room_goals(mission, rooms, costmap, start, nodes)
    return Placement(world, start, room_goals)


def check_docks(
    mission: Setup,
    robot: RobotDescription,
    docks: dict[str, Dock],
    file_docks: dict[str, Dock],
    costmap: Costmap,
    report: Report,
    nodes: Sequence[NodeCheck] = (),
) -> None:
    """The rooms file's docks on the map and free; each ``dock`` node names a dock the
    robot fits on, with a staging pose it can plan to; ``charge`` needs a battery."""
    for dock in file_docks.values():
        problem = dock_problem(dock.pose, costmap.grid)
        if problem is not None:
            report(("rooms",), f"{dock.source}: docks.{dock.name}: {problem}")
    margin = goal_margin(mission.stack.global_planner)
    for path, ports, node_report in nodes:
        if ports.type == "charge" and robot.battery is None:
            node_report(path, f"robot {robot.name!r} has no battery (give it `battery:`)")
        if ports.type != "dock":
            continue
        dock = docks.get(ports.dock)
        where = (*path, "dock")
        if dock is None:
            known = ", ".join(sorted(docks)) or "(none: list `docks:` in a world or rooms file)"
            node_report(where, f"unknown dock {ports.dock!r}; known docks: {known}")
            continue
        named = f"dock {ports.dock!r}"
        _check_pose(dock.pose, costmap, where, _prefixed(node_report, f"{named} at "))
        staging = dock.staging()
        _check_pose(
            staging, costmap, where, _prefixed(node_report, f"{named}'s staging pose "), margin
        )


def _prefixed(report: Report, prefix: str) -> Report:
    return lambda path, message: report(path, prefix + message)


def start_pose(
    mission: Setup, world: World, rooms: dict[str, Room], costmap: Costmap, report: Report
) -> Pose2D:
    """``start`` as a pose: the world's spawn, a room's anchor (or, without one, a free
    point well inside it: :func:`room_point`), or as given."""
    if mission.start is None:
        return world.spawn
    if isinstance(mission.start, str):
        room = rooms.get(mission.start)
        if room is None:
            report(
                ("start",),
                f"unknown room {mission.start!r}; known rooms: "
                f"{', '.join(sorted(rooms)) or '(none)'}",
            )
            return world.spawn
        if room.anchor is None:
            free = costmap.distance > costmap.robot_radius + START_MARGIN
            point = room_point(room, costmap, free)
            if point is None:
                report(("start",), f"room {mission.start!r} has no free point to start from")
                return world.spawn
            return point
        return room.anchor
    return mission.start.to_pose2d()


def grid_cells(extent: tuple[float, float, float, float], resolution: float) -> float:
    """Cells of a grid covering ``extent`` at ``resolution`` (a float: it may be huge)."""
    xmin, xmax, ymin, ymax = extent
    return math.ceil((xmax - xmin) / resolution) * math.ceil((ymax - ymin) / resolution)


def _with_obstacles(world: World, obstacles: list[Any]) -> World:
    """The world with unmapped obstacles added to its geometry (its map stays as it was)."""
    boxes = list(world.boxes)
    cylinders = list(world.cylinders)
    for o in obstacles:
        if o.type == "box":
            boxes.append(Box(o.x, o.y, o.size_x / 2.0, o.size_y / 2.0, o.yaw))
        else:
            cylinders.append(Cylinder(o.x, o.y, o.radius))
    return dataclasses.replace(world, boxes=boxes, cylinders=cylinders)


def _distance_to_obstacle(o: Any, x: float, y: float) -> float:
    if o.type == "cylinder":
        return math.hypot(x - o.x, y - o.y) - o.radius
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    lx, ly = c * (x - o.x) + s * (y - o.y), -s * (x - o.x) + c * (y - o.y)
    dx, dy = max(abs(lx) - o.size_x / 2.0, 0.0), max(abs(ly) - o.size_y / 2.0, 0.0)
    return math.hypot(dx, dy)


def _room_goals(
    mission: Setup,
    rooms: dict[str, Room],
    costmap: Costmap,
    start: Pose2D,
    nodes: Sequence[NodeCheck],
) -> dict[str, Pose2D]:
    """Where each visited room is entered: its anchor, or a reachable point well inside."""
    goals: dict[str, Pose2D] = {}
    allowed: np.ndarray | None = None
    for path, ports, report in nodes:
        for sub, label in ports.rooms_named():
            if label not in rooms:
                report(
                    path + sub,
                    f"unknown room {label!r}; known rooms: "
                    f"{', '.join(sorted(rooms)) or '(none: give a rooms file)'}",
                )
        for sub, label in ports.rooms_visited():
            room = rooms.get(label)
            if label in goals or room is None:
                continue
            if room.anchor is not None:
                margin = goal_margin(mission.stack.global_planner)
                _check_pose(room.anchor, costmap, path + sub, report, margin)
                goals[label] = room.anchor
                continue
            if allowed is None:
                allowed = reachable_cells(costmap, start, margin=0.1)
            point = room_point(room, costmap, allowed)
            if point is None:
                report(path + sub, f"room {label!r} has no free point the robot can reach")
            else:
                goals[label] = point
    return goals


def _check_map_areas(
    mission: Setup, extent: tuple[float, float, float, float], nodes: Sequence[NodeCheck]
) -> None:
    """Areas to map overlap the world's map, and SLAM's grid over them fits."""
    xmin, xmax, ymin, ymax = extent
    resolution = float(getattr(mission.stack.slam, "resolution", 0.05))
    for path, ports, report in nodes:
        for sub, area in ports.map_bounds():
            bounds = area.as_tuple() if area is not None else extent
            bx0, bx1, by0, by1 = bounds
            if bx1 <= xmin or bx0 >= xmax or by1 <= ymin or by0 >= ymax:
                report(
                    path + sub,
                    f"(x {bx0:g}..{bx1:g}, y {by0:g}..{by1:g}) do not overlap the map "
                    f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
                )
                continue
            cells = grid_cells(bounds, resolution)
            if cells > MAX_GRID_CELLS:
                report(
                    path + sub,
                    f"a SLAM map of these bounds at {resolution:g} m has {cells:.3g} cells; at "
                    f"most {MAX_GRID_CELLS:.3g} (smaller bounds or a coarser stack.slam.resolution)",
                )


def _check_pose(
    pose: Pose2D, costmap: Costmap, field_path: FieldPath, report: Report, margin: float = 0.0
) -> None:
    """A pose on the map, in known free space, with the robot's radius (and, for a goal,
    the planner's ``margin``) clear of obstacles."""
    xmin, xmax, ymin, ymax = costmap.grid.extent
    xy = np.array([pose.x, pose.y])
    if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.yaw)):
        report(
            field_path,
            f"(x {pose.x:g}, y {pose.y:g}, yaw {pose.yaw:g}) is not a finite pose",
        )
    elif not (xmin <= pose.x < xmax and ymin <= pose.y < ymax):
        report(
            field_path,
            f"({pose.x:g}, {pose.y:g}) is outside the map "
            f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})",
        )
    elif costmap.grid.value_at(xy) == UNKNOWN:
        report(field_path, f"({pose.x:g}, {pose.y:g}) lies in unknown space of the map")
    elif not costmap.is_free(xy, margin):
        clearance = float(costmap.clearance(xy))
        needs = f"robot radius {costmap.robot_radius:.3f} m"
        if margin > 0:
            needs += f" + the planner's clearance {margin:.3f} m"
        report(
            field_path,
            f"({pose.x:g}, {pose.y:g}) is inside or too close to an obstacle "
            f"(clearance {clearance:.3f} m; needs more than {needs})",
        )
