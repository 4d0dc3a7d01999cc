"""Worlds: the physical layout the simulator builds and the map the robot knows.

A :class:`World` is pure data: wall boxes and cylinders (what MuJoCo simulates), the
occupancy grid the robot is given (rasterised from the geometry, or a ROS map), a spawn
pose, named rooms and named docks (chargers).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room


@dataclass(frozen=True)
class Box:
    """An axis-aligned-in-its-own-frame box: centre, half extents, yaw. Height is the world's."""

    x: float
    y: float
    half_x: float
    half_y: float
    yaw: float = 0.0


@dataclass(frozen=True)
class Cylinder:
    """A vertical cylinder (pillar)."""

    x: float
    y: float
    radius: float


@dataclass
class World:
    """Everything about the environment a mission needs."""

    name: str
    boxes: list[Box]
    cylinders: list[Cylinder]
    map: OccupancyGrid  # what the robot is told (static map)
    spawn: Pose2D
    rooms: dict[str, Room] = field(default_factory=dict)
    wall_height: float = 0.5
    docks: dict[str, Dock] = field(default_factory=dict)
    # what reading a Gazebo world left out (``skipped``, ``not_cut``): result.json's
    # ``world_import``; empty for every other world
    imported: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class RoomPoint:
    """Where a room is visited: its anchor, or (``kind`` "inside") its inside point."""

    label: str
    point: Pose2D
    kind: str  # "anchor" or "inside"


@dataclass(frozen=True)
class WorldDescription:
    """What a user needs to write a mission for a world: its extent, spawn and rooms."""

    name: str
    extent: tuple[float, float, float, float]  # xmin, xmax, ymin, ymax of its map
    spawn: Pose2D
    rooms: list[RoomPoint]


def describe(world: World) -> WorldDescription:
    rooms = []
    for label, room in world.rooms.items():
        if room.anchor is not None:
            rooms.append(RoomPoint(label, room.anchor, "anchor"))
        else:
            x, y = room.inside_point()
            rooms.append(RoomPoint(label, Pose2D(x, y, 0.0), "inside"))
    return WorldDescription(world.name, world.map.extent, world.spawn, rooms)
