"""Resolve a mission's ``world:`` value into a :class:`World`.

``load_world(spec, base_dir)`` accepts, in this order:

1. the name of a built-in world (``turtlebot3_world``, ``small_house``, ``warehouse``,
   ``depot``);
2. a path (relative paths against ``base_dir``, the mission file's folder) to a ROS
   ``map_server`` YAML (``image`` + ``resolution`` + ``origin``; a folder holding a
   ``map.yaml`` works too). The loaded grid is the robot's map; every occupied cell
   becomes part of a wall box (runs of a row merged, identical runs of consecutive
   rows stacked; or the same by columns when that gives fewer boxes), so the
   simulated world matches the map cell for cell. The spawn is
   the free cell nearest the map-frame origin (0, 0) with at least
   :data:`SPAWN_CLEARANCE` of free space around it (in the largest free region),
   else (0, 0). No rooms: give a rooms file;
3. a path to a Gazebo world (``.world`` or ``.sdf``, :mod:`agv_mission.maps.sdf_world`),
   its bodies cut at ``scan_height``; its map the cut rasterised at 0.05 m over the
   geometry's bounds plus 2 m; spawn (0, 0, 0), where Gazebo spawns; no rooms;
4. a path to a world file in this module's own YAML format::

       name: my_arena              # optional; default: the file's stem
       resolution: 0.05            # optional, metres per map cell
       bounds: {xmin: -3, xmax: 3, ymin: -3, ymax: 3}
                                   # optional; default: the geometry's bounding box + 0.5 m
       wall_height: 0.5            # optional, metres
       spawn: {x: 0.0, y: 0.0, yaw: 0.0}                 # required
       boxes:                      # optional; centre, half extents, yaw (rad)
         - {x: 0.0, y: 2.55, half_x: 3.0, half_y: 0.05, yaw: 0.0}
         - {x: 1.0, y: 1.0, size: [0.5, 0.3]}           # or full sizes instead of halves
       cylinders:                  # optional
         - {x: 1.1, y: 1.1, radius: 0.15}
       rooms:                      # optional: the rooms file's mapping, or a path to one
         kitchen:
           polygon: [[0, 0], [2, 0], [2, 2], [0, 2]]
           anchor: {x: 1.0, y: 1.0, yaw: 0.0}
       docks:                      # optional: chargers, the docked robot's pose
         charger: {x: 0.0, y: -2.2, yaw: -1.5708}

   The robot's map is rasterised from the geometry
   (:func:`agv_mission.maps.rasterize.rasterize`): free where the spawn can reach.

Anything else raises :class:`WorldError`, whose message lists the built-in names.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from agv_mission.atomic import InputFileError, input_path, read_input_text
from agv_mission.geometry import Pose2D
from agv_mission.maps.builtin_worlds import BUILTIN_WORLDS
from agv_mission.maps.docks import Dock, DockModel, dock_problem
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid
from agv_mission.maps.rasterize import (
    WorldTooLarge,
    grid_shape,
    occupancy_mask,
    rasterize,
)
from agv_mission.maps.rooms import Room
from agv_mission.maps.rooms_file import (
    RoomsFileError,
    compose_nodes,
    load_rooms_file,
    node_line,
    rooms_from_doc,
)
from agv_mission.maps.ros_map import MapLoadError, is_ros_map_yaml, load_ros_map
from agv_mission.maps.sdf_world import SdfError, is_sdf_path, read_sdf_world
from agv_mission.maps.worlds import Box, Cylinder, World
from agv_mission.suggest import unknown_key
from agv_mission.yaml_safe import safe_load

SPAWN_CLEARANCE = 0.3  # metres of free space the spawn of a ROS map must have around it
DEFAULT_RESOLUTION = 0.05
DEFAULT_MARGIN = 0.5
SDF_MAP_MARGIN = 2.0  # m around a Gazebo world's bodies (robots-and-worlds.md)
#: The scan plane a Gazebo world is cut at when no robot says (LidarSpec's default height).
DEFAULT_SCAN_HEIGHT = 0.17


class WorldError(ValueError):
    """A ``world:`` value that names no built-in world and no readable world/map file.
    ``problems`` holds one line a problem (``file:line: field: message``) when there are
    several."""

    def __init__(self, message: str, problems: Sequence[str] = ()) -> None:
        super().__init__(message)
        self.problems = list(problems)


def builtin_names() -> list[str]:
    return sorted(BUILTIN_WORLDS)


def load_world(
    spec: str,
    base_dir: Path | str = ".",
    scan_height: float = DEFAULT_SCAN_HEIGHT,
    skip_unsupported: bool = False,
) -> World:
    """The world named by ``spec``: a built-in name, a ROS map YAML, a Gazebo world (cut
    at ``scan_height``, what it cannot read skipped with ``skip_unsupported``) or a world
    file."""
    spec = str(spec).strip()
    if spec in BUILTIN_WORLDS:
        return BUILTIN_WORLDS[spec]()
    names = ", ".join(builtin_names())
    if not spec:
        raise WorldError(f"empty world name; built-in worlds are: {names}")
    path = input_path(spec, base_dir)
    if path.is_dir() and (path / "map.yaml").is_file():
        path = path / "map.yaml"
    if not path.exists():
        raise WorldError(
            f"unknown world {spec!r}: not a built-in world ({names}) and no such file {path}"
        )
    if is_sdf_path(path):
        return world_from_sdf(path, scan_height, skip_unsupported)
    try:
        text = read_input_text(path)
        doc = safe_load(text)
    except InputFileError as exc:
        raise WorldError(f"{path}: world file: {exc}") from None
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise WorldError(f"{path}: cannot read world file: {exc}") from exc
    if is_ros_map_yaml(doc):
        return world_from_ros_map(path)
    if isinstance(doc, dict):
        return world_from_file(path, doc, compose_nodes(text))
    raise WorldError(
        f"{path}: neither a ROS map YAML (image, resolution, origin) nor a world file "
        f"(spawn, boxes, cylinders, ...); built-in worlds are: {names}"
    )


# --------------------------------------------------------------------------- Gazebo worlds


def world_from_sdf(path: Path, scan_height: float, skip_unsupported: bool = False) -> World:
    """A Gazebo world's static bodies cut at ``scan_height``; what was left out in
    :attr:`World.imported`."""
    try:
        sdf = read_sdf_world(path, scan_height, skip_unsupported)
    except SdfError as exc:
        raise WorldError(str(exc), exc.problems) from None
    imported: dict[str, Any] = {}
    if sdf.skipped or skip_unsupported:
        imported["skipped"] = sdf.skipped
    if sdf.not_cut:
        imported["not_cut"] = sdf.not_cut
    try:
        grid = open_floor_map(sdf.boxes, sdf.cylinders)
    except WorldTooLarge as exc:
        raise _too_large(path, sdf, exc) from None
    return World(
        name=sdf.name,
        boxes=sdf.boxes,
        cylinders=sdf.cylinders,
        map=grid,
        spawn=Pose2D(0.0, 0.0, 0.0),
        rooms={},
        wall_height=max(scan_height + 0.3, 0.5),
        imported=imported,
    )


def _too_large(path: Path, sdf: Any, exc: WorldTooLarge) -> WorldError:
    """The bodies that stretch a Gazebo world's map past the cells it may hold: those
    reaching farthest west, east, south and north, each at its line."""
    bodies = [(*_reach(b), src) for b, src in zip(sdf.boxes, sdf.box_sources, strict=True)] + [
        (c.x - c.radius, c.x + c.radius, c.y - c.radius, c.y + c.radius, src)
        for c, src in zip(sdf.cylinders, sdf.cylinder_sources, strict=True)
    ]
    ends = [min(bodies, key=lambda b: b[0]), max(bodies, key=lambda b: b[1])]
    ends += [min(bodies, key=lambda b: b[2]), max(bodies, key=lambda b: b[3])]
    problems = [
        f"{src}: reaches x {x0:.4g}..{x1:.4g} m, y {y0:.4g}..{y1:.4g} m"
        for x0, x1, y0, y1, src in dict.fromkeys(ends)
    ]
    message = f"{path}: the world's map is too large: {exc}; the bodies that stretch it:"
    return WorldError(message + "".join(f"\n  {p}" for p in problems), problems)


def _reach(b: Box) -> tuple[float, float, float, float]:
    """xmin, xmax, ymin, ymax of a (rotated) box."""
    c, s = abs(math.cos(b.yaw)), abs(math.sin(b.yaw))
    ex, ey = c * b.half_x + s * b.half_y, s * b.half_x + c * b.half_y
    return b.x - ex, b.x + ex, b.y - ey, b.y + ey


def open_floor_map(
    boxes: list[Box], cylinders: list[Cylinder], margin: float = SDF_MAP_MARGIN
) -> OccupancyGrid:
    """A Gazebo world's own map: its bodies rasterised at :data:`DEFAULT_RESOLUTION` over
    their bounds plus ``margin`` (around the origin for an empty world). A Gazebo world is
    open floor: every cell no body touches is free."""
    if boxes or cylinders:
        bounds = _geometry_bounds(boxes, cylinders, None, margin)
    else:
        bounds = (-margin, margin, -margin, margin)
    shape = grid_shape(bounds, DEFAULT_RESOLUTION)
    origin = Pose2D(float(bounds[0]), float(bounds[2]), 0.0)
    occupied = occupancy_mask(boxes, cylinders, shape, DEFAULT_RESOLUTION, origin)
    return OccupancyGrid(
        np.where(occupied, OCCUPIED, FREE).astype(np.int8), DEFAULT_RESOLUTION, origin
    )


# --------------------------------------------------------------------------- ROS maps


def world_from_ros_map(yaml_path: Path | str, spawn_clearance: float = SPAWN_CLEARANCE) -> World:
    """A world whose walls are the occupied cells of a ``map_server`` map."""
    yaml_path = Path(yaml_path)
    try:
        grid = load_ros_map(yaml_path)
    except MapLoadError as exc:
        raise WorldError(str(exc)) from exc
    name = (
        yaml_path.parent.name
        if yaml_path.stem == "map" and yaml_path.parent.name
        else yaml_path.stem
    )
    return World(
        name=name,
        boxes=occupied_boxes(grid),
        cylinders=[],
        map=grid,
        spawn=find_spawn(grid, spawn_clearance),
        rooms={},
    )


def occupied_runs(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """Rectangles ``(row0, row1, col0, col1)`` (inclusive) covering the True cells exactly.

    Each row's runs of True cells are found, then identical runs (same columns) in
    consecutive rows are stacked into one rectangle. The rectangles are disjoint.
    """
    occupied = np.asarray(occupied, dtype=bool)
    rects: list[tuple[int, int, int, int]] = []
    active: dict[tuple[int, int], int] = {}  # (col0, col1) -> first row
    padded = np.zeros(occupied.shape[1] + 2, dtype=np.int8)
    for row in range(occupied.shape[0]):
        padded[1:-1] = occupied[row]
        edges = np.flatnonzero(np.diff(padded))
        runs = {(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True)}
        for key in [k for k in active if k not in runs]:
            rects.append((active.pop(key), row - 1, key[0], key[1]))
        for key in runs:
            active.setdefault(key, row)
    for key, first in active.items():
        rects.append((first, occupied.shape[0] - 1, key[0], key[1]))
    rects.sort()
    return rects


def occupied_rectangles(occupied: np.ndarray) -> list[tuple[int, int, int, int]]:
    """:func:`occupied_runs` along rows or along columns, whichever gives fewer rectangles."""
    by_rows = occupied_runs(occupied)
    by_cols = [(r0, r1, c0, c1) for c0, c1, r0, r1 in occupied_runs(np.asarray(occupied).T)]
    return by_cols if len(by_cols) < len(by_rows) else by_rows


def occupied_boxes(grid: OccupancyGrid) -> list[Box]:
    """Disjoint wall boxes covering exactly the grid's occupied cells."""
    res = grid.resolution
    c, s = math.cos(grid.origin.yaw), math.sin(grid.origin.yaw)
    boxes = []
    for r0, r1, c0, c1 in occupied_rectangles(grid.data == OCCUPIED):
        px = (c0 + c1 + 1) * res / 2.0
        py = (r0 + r1 + 1) * res / 2.0
        boxes.append(
            Box(
                x=grid.origin.x + c * px - s * py,
                y=grid.origin.y + s * px + c * py,
                half_x=(c1 + 1 - c0) * res / 2.0,
                half_y=(r1 + 1 - r0) * res / 2.0,
                yaw=grid.origin.yaw,
            )
        )
    return boxes


def find_spawn(grid: OccupancyGrid, clearance: float = SPAWN_CLEARANCE) -> Pose2D:
    """The free cell nearest (0, 0) whose centre is more than ``clearance`` from the
    nearest non-free cell's edge, within the largest such free region; else (0, 0)."""
    free = grid.data == FREE
    if not free.any():
        return Pose2D(0.0, 0.0, 0.0)
    from scipy import ndimage  # ~0.5 s: a ROS map's, not a built-in world's

    distance = (ndimage.distance_transform_edt(free) - 0.5) * grid.resolution
    roomy = free & (distance > clearance)
    labels, count = ndimage.label(roomy)
    if count == 0:
        return Pose2D(0.0, 0.0, 0.0)
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    rows, cols = np.nonzero(labels == int(np.argmax(sizes)))
    centres = grid.cell_to_world(rows, cols)
    best = int(np.argmin(np.hypot(centres[:, 0], centres[:, 1])))
    return Pose2D(round(float(centres[best, 0]), 6), round(float(centres[best, 1]), 6), 0.0)


# --------------------------------------------------------------------------- world files


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", defer_build=True)


class _PoseModel(_Strict):
    x: float
    y: float
    yaw: float = 0.0


class _BoundsModel(_Strict):
    xmin: float
    xmax: float
    ymin: float
    ymax: float

    @model_validator(mode="after")
    def _non_empty(self) -> _BoundsModel:
        if not (self.xmax > self.xmin and self.ymax > self.ymin):
            raise ValueError("need xmax > xmin and ymax > ymin")
        return self


class _BoxModel(_Strict):
    x: float
    y: float
    half_x: float | None = Field(None, gt=0)
    half_y: float | None = Field(None, gt=0)
    size: tuple[float, float] | None = None
    yaw: float = 0.0

    @model_validator(mode="after")
    def _extent(self) -> _BoxModel:
        halves = self.half_x is not None and self.half_y is not None
        if halves == (self.size is not None):
            raise ValueError("give either half_x and half_y, or size: [sx, sy]")
        if self.size is not None and min(self.size) <= 0:
            raise ValueError("size must be positive")
        return self

    def to_box(self) -> Box:
        if self.size is not None:
            hx, hy = self.size[0] / 2.0, self.size[1] / 2.0
        else:
            hx, hy = float(self.half_x), float(self.half_y)  # type: ignore[arg-type]
        return Box(self.x, self.y, hx, hy, self.yaw)


class _CylinderModel(_Strict):
    x: float
    y: float
    radius: float = Field(..., gt=0)


class WorldFileModel(_Strict):
    """The world file format (see the module docstring)."""

    name: str | None = None
    resolution: float = Field(DEFAULT_RESOLUTION, gt=0)
    bounds: _BoundsModel | None = None
    wall_height: float = Field(0.5, gt=0)
    spawn: _PoseModel
    boxes: list[_BoxModel] = Field(default_factory=list)
    cylinders: list[_CylinderModel] = Field(default_factory=list)
    rooms: str | dict[str, Any] | None = None
    docks: dict[str, DockModel] = Field(default_factory=dict)


def world_from_file(
    path: Path, doc: dict[str, Any] | None = None, root: yaml.Node | None = None
) -> World:
    """Build a world from a world file (already parsed as ``doc`` if given; ``root``, its
    YAML node tree, gives each problem its line)."""
    if doc is None:
        try:
            doc = safe_load(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
            raise WorldError(f"{path}: cannot read world file: {exc}") from exc
    try:
        model = WorldFileModel.model_validate(doc)
    except ValidationError as exc:
        details = [
            (
                node_line(root, tuple(err["loc"])) if root is not None else None,
                f"{'.'.join(str(p) for p in err['loc']) or '(top level)'}: "
                + _world_file_message(err),
            )
            for err in exc.errors()
        ]
        raise WorldError(
            f"{path}: invalid world file:\n" + "\n".join(f"  {d}" for _, d in details),
            [f"{path}:{line}: {d}" if line else f"{path}: {d}" for line, d in details],
        ) from exc

    boxes = [b.to_box() for b in model.boxes]
    cylinders = [Cylinder(c.x, c.y, c.radius) for c in model.cylinders]
    spawn = Pose2D(model.spawn.x, model.spawn.y, model.spawn.yaw)
    if model.bounds is not None:
        b = model.bounds
        bounds = (b.xmin, b.xmax, b.ymin, b.ymax)
    else:
        bounds = _geometry_bounds(boxes, cylinders, spawn, DEFAULT_MARGIN)
    try:
        grid = rasterize(boxes, cylinders, bounds, model.resolution, spawn)
    except WorldTooLarge as exc:  # refused before a cell is allocated
        line = node_line(root, ("bounds",)) if root is not None and model.bounds else None
        if line is None:  # the bodies stretch the map
            raise WorldError(f"{path}: {exc}") from None
        message = f"{path}:{line}: bounds: {exc} (smaller bounds or a coarser resolution)"
        raise WorldError(message, [message]) from None
    except ValueError as exc:
        raise WorldError(f"{path}: {exc}") from exc
    rooms, docks = _rooms_of(path, model.rooms, root)
    for name, d in model.docks.items():
        line = node_line(root, ("docks", name)) if root is not None else None
        docks[name] = Dock(name, Pose2D(d.x, d.y, d.yaw), f"{path}:{line}" if line else str(path))
    for dock in docks.values():
        problem = dock_problem(dock.pose, grid)
        if problem is not None:
            raise WorldError(f"{dock.source}: docks.{dock.name}: {problem}")
    return World(
        name=model.name or path.stem,
        boxes=boxes,
        cylinders=cylinders,
        map=grid,
        spawn=spawn,
        rooms=rooms,
        wall_height=model.wall_height,
        docks=docks,
    )


def _world_file_message(err: Any) -> str:
    if err["type"] == "missing":
        return "field required"
    if err["type"] == "extra_forbidden":
        return unknown_key(WorldFileModel, tuple(err["loc"]))
    return str(err["msg"]).removeprefix("Value error, ")


def _rooms_of(
    path: Path, rooms: str | dict[str, Any] | None, root: yaml.Node | None = None
) -> tuple[dict[str, Room], dict[str, Dock]]:
    """The world's rooms, and the docks of its rooms file when it names one."""
    try:
        if rooms is None:
            return {}, {}
        if isinstance(rooms, str):
            return load_rooms_file(input_path(rooms, path.parent))
        return rooms_from_doc(path, rooms, root), {}
    except RoomsFileError as exc:
        raise WorldError(str(exc), exc.lines()) from exc


def _geometry_bounds(
    boxes: list[Box], cylinders: list[Cylinder], spawn: Pose2D | None, margin: float
) -> tuple[float, float, float, float]:
    xs, ys = ([spawn.x], [spawn.y]) if spawn is not None else ([], [])
    for b in boxes:
        c, s = abs(math.cos(b.yaw)), abs(math.sin(b.yaw))
        ex, ey = c * b.half_x + s * b.half_y, s * b.half_x + c * b.half_y
        xs += [b.x - ex, b.x + ex]
        ys += [b.y - ey, b.y + ey]
    for cyl in cylinders:
        xs += [cyl.x - cyl.radius, cyl.x + cyl.radius]
        ys += [cyl.y - cyl.radius, cyl.y + cyl.radius]
    return (min(xs) - margin, max(xs) + margin, min(ys) - margin, max(ys) + margin)
