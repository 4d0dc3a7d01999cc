"""Live-stream messages (service-api.md + coord STREAM.md), built from run observations.

Every message is a JSON-ready dict with a ``type``; poses are ``{x, y, yaw}``; numbers are
rounded so that a scan stays a few kilobytes.
"""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.json_values import json_default
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.grid_image import grid_png
from agv_mission.maps.rooms import Room
from agv_mission.missions.report.palette import robot_colour
from agv_mission.missions.run.observe import RunStart
from agv_mission.missions.run.samples import TreeNode

MAX_PARTICLES = 300
TREE_STATUS = {
    "succeeded": "SUCCESS",
    "failed": "FAILURE",
    "running": "RUNNING",
    "not_run": "INVALID",
}


def dumps(message: dict[str, Any]) -> str:
    return json.dumps(message, separators=(",", ":"), allow_nan=False, default=json_default)


def pose(p: Pose2D | None) -> dict[str, float] | None:
    if p is None:
        return None
    return {"x": round(p.x, 4), "y": round(p.y, 4), "yaw": round(p.yaw, 4)}


def xy_list(points: np.ndarray | None, columns: int = 2) -> list[list[float]]:
    if points is None or not len(points):
        return []
    arr = np.asarray(points, dtype=float)[:, :columns]
    arr = arr[np.all(np.isfinite(arr), axis=1)]
    return np.round(arr, 3).tolist()


def map_message(grid: OccupancyGrid) -> dict[str, Any]:
    """The map as map_saver would write it (254 free, 0 occupied, 205 unknown), PNG, row 0
    at the top."""
    return {"type": "map", **grid_png(grid)}


def people_message(t: float, ids: Any, xy: Any, radii: Any) -> dict[str, Any]:
    """The people in the world: ``[id, x, y, radius]`` each (people-and-zones.md)."""
    rows = [
        [int(i), round(float(x), 3), round(float(y), 3), round(float(r), 3)]
        for i, (x, y), r in zip(ids, xy, radii, strict=True)
    ]
    return {"type": "people", "t": round(t, 3), "people": rows}


def zones_message(keepout: OccupancyGrid | None, speed: OccupancyGrid | None) -> dict[str, Any]:
    """The keepout (red) and speed (blue, darker: slower) filter masks as one RGBA PNG on
    the masks' grid, row 0 at the top."""
    grid = keepout if keepout is not None else speed
    assert grid is not None
    rgba = np.zeros((grid.height, grid.width, 4), dtype=np.uint8)
    if speed is not None:
        limited = speed.data > 0
        rgba[limited] = (40, 90, 255, 0)
        rgba[limited, 3] = (60 + 1.2 * (100 - speed.data[limited].astype(np.int16))).astype(
            np.uint8
        )
    if keepout is not None:
        rgba[keepout.data >= 65] = (217, 70, 60, 120)
    return {"type": "zones", **grid_png(grid, np.ascontiguousarray(rgba[::-1]), "RGBA")}


def rooms_message(rooms: dict[str, Room], docks: dict[str, Dock] | None = None) -> dict[str, Any]:
    """The rooms, and the docks (chargers) as ``{name, x, y, yaw}``."""
    return {
        "type": "rooms",
        "rooms": [
            {
                "label": r.label,
                "polygon": [[round(x, 4), round(y, 4)] for x, y in r.polygon],
                "anchor": pose(r.anchor),
            }
            for r in rooms.values()
        ],
        "docks": [{"name": d.name, **pose(d.pose)} for d in (docks or {}).values()],
    }


def recorded_message(entries: dict[str, Pose2D]) -> dict[str, Any]:
    return {"type": "recorded", "entries": {k: pose(p) for k, p in entries.items()}}


def tree_nodes(nodes: list[TreeNode]) -> list[dict[str, Any]]:
    return [
        {"name": n.name, "status": TREE_STATUS.get(n.status, n.status), "depth": n.depth}
        for n in nodes
    ]


def tree_message(nodes: list[TreeNode], robot: str) -> dict[str, Any]:
    return {"type": "tree", "robot": robot, "nodes": tree_nodes(nodes)}


def robots_message(start: RunStart) -> dict[str, Any]:
    """Every robot of the run: name, model, colour, footprint, start and tree."""
    from agv_mission.service.models import StreamRobots

    message = StreamRobots(
        fleet=start.fleet,
        robots=[
            {
                "name": r.name,
                "type": r.robot.name,
                "colour": robot_colour(k),
                "radius": r.robot.footprint_radius,
                "footprint": r.robot.footprint,
                "start": pose(r.start),
                "tree": tree_nodes(r.tree_nodes),
            }
            for k, r in enumerate(start.robots)
        ],
    )
    return message.model_dump()


def detail_of(nodes: list[TreeNode] | None) -> str:
    """A one-line summary: the deepest running behaviour's path below its task."""
    if not nodes:
        return ""
    running = [n for n in nodes if n.status in ("running", "RUNNING") and n.depth >= 1]
    if not running:
        return ""
    names = [n.name for n in running]
    return " > ".join(names[-2:]) if len(names) > 1 else names[0]


def particles_list(particles: np.ndarray) -> list[list[float]]:
    p = np.asarray(particles, dtype=float)
    if len(p) > MAX_PARTICLES:
        p = p[np.linspace(0, len(p) - 1, MAX_PARTICLES).astype(int)]
    return np.round(p[:, :3], 3).tolist()


def covariance_list(cov: np.ndarray | None) -> list[list[float]] | None:
    if cov is None:
        return None
    arr = np.asarray(cov, dtype=float)
    if arr.shape != (3, 3) or not np.all(np.isfinite(arr)):
        return None
    return np.round(arr, 6).tolist()
