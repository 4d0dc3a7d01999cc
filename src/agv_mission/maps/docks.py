"""Docks: named charger poses of a world or rooms file (``docks: {NAME: {x, y, yaw}}``).

A dock's pose is where the robot's centre stands when docked, facing the charger (Nav2's
docking server puts it the same way). The robot comes to it from a staging pose
``STAGING_DISTANCE`` in front, straight and slowly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from agv_mission.geometry import Pose2D
from agv_mission.maps.grid import OccupancyGrid

#: metres in front of the dock where the final approach starts (Nav2 docking's
#: ``staging_x_offset`` default, 0.7 m)
STAGING_DISTANCE = 0.7


class DockModel(BaseModel):
    """One dock as a file writes it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    x: float
    y: float
    yaw: float = Field(0.0, description="the heading of the docked robot (towards the charger)")


@dataclass(frozen=True)
class Dock:
    """A named dock; ``source`` says where it was written (``file:line``), for messages."""

    name: str
    pose: Pose2D
    source: str = ""

    def staging(self, distance: float = STAGING_DISTANCE) -> Pose2D:
        """The pose ``distance`` in front of the dock, facing it."""
        p = self.pose
        return Pose2D(p.x - distance * math.cos(p.yaw), p.y - distance * math.sin(p.yaw), p.yaw)


def dock_problem(pose: Pose2D, grid: OccupancyGrid) -> str | None:
    """Why ``pose`` cannot be a dock on ``grid`` (outside the map, not on a free cell)."""
    xmin, xmax, ymin, ymax = grid.extent
    if not (xmin <= pose.x < xmax and ymin <= pose.y < ymax):
        return (
            f"({pose.x:g}, {pose.y:g}) is outside the map "
            f"(x {xmin:g}..{xmax:g}, y {ymin:g}..{ymax:g})"
        )
    value = int(grid.value_at(np.array([[pose.x, pose.y]]))[0])
    if not 0 <= value <= 50:  # unknown (-1) or occupied
        return f"({pose.x:g}, {pose.y:g}) is not on a free cell of the map"
    return None
