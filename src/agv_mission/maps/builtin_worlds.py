"""Built-in worlds: the TurtleBot3 arena and a small house, as boxes, cylinders and rooms.

Both worlds use 0.05 m maps rasterised from their own geometry
(:func:`agv_mission.maps.rasterize.rasterize`), so the robot's map and the simulated
world agree exactly. Walls are thin boxes (0.1 m).

``turtlebot3_world``
    The hexagonal arena of ROBOTIS' ``turtlebot3_world`` with nine pillars (r = 0.15 m)
    at x, y in {-1.1, 0, 1.1}. The hexagon is regular, pointed along x, with its inner
    wall faces 2.5 m from the centre: a least-squares fit of the six straight wall
    panels of the real ``map_saver`` map (``tests/data/ros_maps/turtlebot3_world``,
    fitted apothems 2.47..2.52 m, normals within 1.5 deg of 30 + 60 k). The real
    arena's small jogs near the four slanted corners are left out. Spawn (-2.0, -0.5, 0)
    as in the TurtleBot3 launch files. Rooms: ``center`` (the pillar square) and the
    ``north``, ``south``, ``east``, ``west`` bands around it.

``small_house``
    A 18.9 x 11.0 m house laid out like the AWS RoboMaker small house (compare
    ``tests/data/ros_maps/aws_small_house``): a bedroom wing on the west, the living
    room (south) and recreation room (north) in the middle, the kitchen wing on the
    east. Four 1.2 m doorways: bedroom-livingroom, livingroom-recreationroom,
    livingroom-kitchen, recreationroom-kitchen. Spawn (3.83, -1.23, 0) in the living
    room, as in the AWS launch files.

``warehouse``
    A 30 x 50 m warehouse hall (x in [-15, 15], y in [-25, 25]): a dock zone in the
    south with pallets and building columns, two blocks of seven pallet racks (1.2 m
    deep, 16 m long) with 2.4 m aisles between them, a 4 m cross aisle in the middle,
    3.6 m side aisles along the walls and a back aisle in the north. Each rack is a
    solid pallet row with uprights standing 0.1 m proud of both faces every 2.7 m
    (one bay), which is what a lidar at wheel height sees of a real rack. Spawn
    (0, -22, pi/2) at the dock.

``depot``
    An open 30 x 15 m depot hall (x in [-15, 15], y in [-7.5, 7.5]) with eight 0.4 m
    building columns on a 6 x 5 m grid, a parked container and pallet stacks along the
    walls: long stretches of open floor. Spawn (-12, 0, 0) at the west gate.

Every world has a dock named ``charger`` by a wall: the docked robot's centre stands
:data:`DOCK_WALL_GAP` from the wall's face, facing it, so a waffle (r = 0.22 m) fits, with
its staging pose 0.7 m further out in open floor. turtlebot3_world: the south wall,
0.55 m east of the middle; small_house: the living room's south wall, east of the TV;
warehouse: in front of the charger block on the west wall of the dock zone; depot: the
south wall by the west gate.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock
from agv_mission.maps.rasterize import rasterize
from agv_mission.maps.rooms import Room
from agv_mission.maps.worlds import Box, Cylinder, World

RESOLUTION = 0.05
WALL_THICKNESS = 0.1
DOCK_WALL_GAP = 0.3  # m from a wall's face to a docked robot's centre


def _charger(x: float, y: float, yaw: float) -> dict[str, Dock]:
    return {"charger": Dock("charger", Pose2D(x, y, yaw), "built-in")}


# --------------------------------------------------------------------------- TurtleBot3

TB3_INNER_APOTHEM = 2.5  # centre to the inner face of each of the six walls, metres
TB3_PILLAR_RADIUS = 0.15
TB3_PILLAR_COORDS = (-1.1, 0.0, 1.1)
TB3_SPAWN = Pose2D(-2.0, -0.5, 0.0)
TB3_BOUNDS = (-3.5, 3.5, -3.5, 3.5)


def hexagon_walls(inner_apothem: float, thickness: float = WALL_THICKNESS) -> list[Box]:
    """Six wall boxes of a regular hexagon pointed along x (flat top and bottom)."""
    apothem = inner_apothem + thickness / 2.0
    side = 2.0 * apothem * math.tan(math.pi / 6.0)
    walls = []
    for k in range(6):
        normal = math.radians(30.0 + 60.0 * k)
        walls.append(
            Box(
                x=apothem * math.cos(normal),
                y=apothem * math.sin(normal),
                half_x=side / 2.0 + thickness / 2.0,  # overlap at the corners
                half_y=thickness / 2.0,
                yaw=normal + math.pi / 2.0,
            )
        )
    return walls


def hexagon_vertices(inner_apothem: float) -> list[tuple[float, float]]:
    """Inner-face corners of the hexagon, counter-clockwise from +x."""
    r = inner_apothem / math.cos(math.pi / 6.0)
    return [
        (r * math.cos(math.radians(60.0 * k)), r * math.sin(math.radians(60.0 * k)))
        for k in range(6)
    ]


def _turtlebot3_rooms() -> dict[str, Room]:
    a = TB3_INNER_APOTHEM
    r = a / math.cos(math.pi / 6.0)
    band = 1.5  # half width of the central square
    xe = r - band / math.sqrt(3.0)  # |x| of the slanted walls at |y| = band
    rooms = [
        Room(
            "center",
            ((-band, -band), (band, -band), (band, band), (-band, band)),
            Pose2D(0.55, 0.55, 0.0),
        ),
        Room(
            "north", ((-xe, band), (xe, band), (r / 2, a), (-r / 2, a)), Pose2D(0.13, 1.93, 1.389)
        ),
        Room(
            "south",
            ((-r / 2, -a), (r / 2, -a), (xe, -band), (-xe, -band)),
            Pose2D(0.55, -1.95, 0.0),
        ),
        Room(
            "east",
            ((band, -band), (xe, -band), (r, 0.0), (xe, band), (band, band)),
            Pose2D(2.0, 0.0, math.pi),
        ),
        Room(
            "west", ((-xe, -band), (-band, -band), (-band, band), (-xe, band), (-r, 0.0)), TB3_SPAWN
        ),
    ]
    return {room.label: room for room in rooms}


def turtlebot3_world() -> World:
    """The TurtleBot3 hexagon arena with nine pillars."""
    boxes = hexagon_walls(TB3_INNER_APOTHEM)
    cylinders = [
        Cylinder(x, y, TB3_PILLAR_RADIUS) for y in TB3_PILLAR_COORDS for x in TB3_PILLAR_COORDS
    ]
    grid = rasterize(boxes, cylinders, TB3_BOUNDS, RESOLUTION, TB3_SPAWN)
    return World(
        name="turtlebot3_world",
        boxes=boxes,
        cylinders=cylinders,
        map=grid,
        spawn=TB3_SPAWN,
        rooms=_turtlebot3_rooms(),
        docks=_charger(0.55, -TB3_INNER_APOTHEM + DOCK_WALL_GAP, -math.pi / 2.0),
    )


# --------------------------------------------------------------------------- small house

HOUSE_SPAWN = Pose2D(3.83, -1.23, 0.0)
HOUSE_BOUNDS = (-10.0, 10.0, -6.0, 6.0)

# Wall centre lines.
_X_WEST, _X_EAST = -9.4, 9.4  # outer walls
_Y_SOUTH = -5.45  # outer wall
_Y_WINGS = 3.1  # north wall of the bedroom and kitchen wings
_Y_NORTH = 5.45  # north wall of the middle block
_X_BED = -2.4  # bedroom | living + recreation
_X_KITCHEN = 4.7  # living + recreation | kitchen
_Y_MID = 0.0  # livingroom | recreationroom

# Doorways (gaps in the wall), 1.2 m wide.
HOUSE_DOORS = {
    "bedroom-livingroom": ("x", _X_BED, (-2.3, -1.1)),
    "livingroom-recreationroom": ("y", _Y_MID, (2.0, 3.2)),
    "livingroom-kitchen": ("x", _X_KITCHEN, (-3.4, -2.2)),
    "recreationroom-kitchen": ("x", _X_KITCHEN, (1.0, 2.2)),
}

HOUSE_ROOMS = {
    "bedroom": (((-9.3, -5.3), (-2.5, -5.3), (-2.5, 3.0), (-9.3, 3.0)), Pose2D(-4.5, -2.5, 0.0)),
    "livingroom": (((-2.3, -5.3), (4.6, -5.3), (4.6, 0.0), (-2.3, 0.0)), Pose2D(3.0, -2.0, 0.0)),
    "recreationroom": (
        ((-2.3, 0.0), (4.6, 0.0), (4.6, 5.3), (-2.3, 5.3)),
        Pose2D(-0.5, 1.8, 0.0),
    ),
    "kitchen": (((4.8, -5.3), (9.3, -5.3), (9.3, 3.0), (4.8, 3.0)), Pose2D(7.0, -2.0, 0.0)),
}

# Furniture as (xmin, xmax, ymin, ymax); pieces against a wall overlap it.
HOUSE_FURNITURE = {
    "bed": (-7.1, -5.2, 1.0, 3.1),
    "nightstand": (-7.7, -7.25, 2.6, 3.1),
    "wardrobe": (-9.4, -8.8, -5.45, -4.0),
    "desk": (-4.5, -3.0, -5.45, -4.9),
    # a 3.5 m lidar in the middle of a bare 7 x 8 m room sees one wall: give it features
    "armchair": (-7.4, -6.6, -2.8, -2.0),
    "bookshelf": (-9.4, -8.95, -2.0, 0.0),
    "sofa": (-0.8, 0.1, -3.05, -0.8),
    "sofa_chaise": (0.1, 1.45, -3.05, -2.2),
    "coffee_table": (0.6, 1.5, -1.9, -1.3),
    "tv_stand": (-0.4, 1.9, -5.45, -4.95),
    "ping_pong_table": (0.2, 2.9, 2.6, 4.1),
    "treadmill": (-2.4, -1.6, 3.5, 5.45),
    "kitchen_counter": (8.75, 9.4, -4.85, -1.6),
    "kitchen_counter_south": (6.7, 9.4, -5.45, -4.85),
    "fridge": (8.7, 9.4, 2.2, 3.1),
    "dining_table": (6.3, 7.6, 0.2, 1.3),
}


def _wall(axis: str, at: float, lo: float, hi: float) -> Box:
    """A wall along ``axis`` ('x': a vertical wall at x = at, spanning y in [lo, hi])."""
    h = WALL_THICKNESS / 2.0
    if axis == "x":
        return Box(at, (lo + hi) / 2.0, h, (hi - lo) / 2.0)
    return Box((lo + hi) / 2.0, at, (hi - lo) / 2.0, h)


def _wall_with_doors(axis: str, at: float, lo: float, hi: float) -> list[Box]:
    gaps = sorted(g for a, pos, g in HOUSE_DOORS.values() if a == axis and pos == at)
    walls, start = [], lo
    for g0, g1 in gaps:
        if g0 > start:
            walls.append(_wall(axis, at, start, g0))
        start = max(start, g1)
    if hi > start:
        walls.append(_wall(axis, at, start, hi))
    return walls


def _rect(xmin: float, xmax: float, ymin: float, ymax: float) -> Box:
    return Box((xmin + xmax) / 2.0, (ymin + ymax) / 2.0, (xmax - xmin) / 2.0, (ymax - ymin) / 2.0)


def small_house_boxes() -> list[Box]:
    h = WALL_THICKNESS / 2.0
    boxes = [
        _wall("x", _X_WEST, _Y_SOUTH - h, _Y_WINGS + h),
        _wall("x", _X_EAST, _Y_SOUTH - h, _Y_WINGS + h),
        _wall("y", _Y_SOUTH, _X_WEST - h, _X_EAST + h),
        _wall("y", _Y_WINGS, _X_WEST - h, _X_BED),
        _wall("y", _Y_WINGS, _X_KITCHEN, _X_EAST + h),
        _wall("y", _Y_NORTH, _X_BED - h, _X_KITCHEN + h),
        *_wall_with_doors("x", _X_BED, _Y_SOUTH, _Y_NORTH),
        *_wall_with_doors("x", _X_KITCHEN, _Y_SOUTH, _Y_NORTH),
        *_wall_with_doors("y", _Y_MID, _X_BED, _X_KITCHEN),
    ]
    boxes.extend(_rect(*extent) for extent in HOUSE_FURNITURE.values())
    return boxes


def small_house() -> World:
    """A four-room house (bedroom, livingroom, recreationroom, kitchen) of about 19 x 11 m."""
    boxes = small_house_boxes()
    grid = rasterize(boxes, [], HOUSE_BOUNDS, RESOLUTION, HOUSE_SPAWN)
    rooms = {
        label: Room(label, polygon, anchor) for label, (polygon, anchor) in HOUSE_ROOMS.items()
    }
    return World(
        name="small_house",
        boxes=boxes,
        cylinders=[],
        map=grid,
        spawn=HOUSE_SPAWN,
        rooms=rooms,
        docks=_charger(3.5, _Y_SOUTH + WALL_THICKNESS / 2.0 + DOCK_WALL_GAP, -math.pi / 2.0),
    )


# --------------------------------------------------------------------------- warehouse

WAREHOUSE_SPAWN = Pose2D(0.0, -22.0, math.pi / 2.0)
WAREHOUSE_BOUNDS = (-15.5, 15.5, -25.5, 25.5)
_WH_X, _WH_Y = 15.0, 25.0  # inner faces of the outer walls
RACK_DEPTH = 1.2
RACK_PITCH = 3.6  # rack + aisle
RACK_XS = tuple(RACK_PITCH * k for k in range(-3, 4))  # seven rack rows
RACK_BLOCKS = ((-18.0, -2.0), (2.0, 18.0))  # y extents of the south and north blocks
BAY = 2.7  # metres between rack uprights
UPRIGHT = 0.1  # upright section, and how far it stands proud of the pallet face
WAREHOUSE_COLUMNS = tuple((x, y) for x in (-7.5, 7.5) for y in (-21.0,))
WAREHOUSE_PALLETS = {  # dock zone: staged pallets (xmin, xmax, ymin, ymax)
    "staging_west": (-12.5, -10.1, -24.9, -23.7),
    "staging_east": (10.1, 12.5, -24.9, -23.7),
    "pallet_1": (-5.0, -3.8, -24.9, -23.9),
    "pallet_2": (3.8, 5.0, -24.9, -23.9),
    "wrapper": (13.6, 14.9, -20.0, -18.8),
    "charger": (-14.9, -14.4, -21.0, -20.0),
}
WAREHOUSE_ROOMS = {
    "dock": (((-14.9, -24.9), (14.9, -24.9), (14.9, -18.1), (-14.9, -18.1)), Pose2D(0, -22, 0)),
    "cross_aisle": (((-14.9, -1.9), (14.9, -1.9), (14.9, 1.9), (-14.9, 1.9)), Pose2D(0, 0, 0)),
    "back_aisle": (((-14.9, 18.1), (14.9, 18.1), (14.9, 24.9), (-14.9, 24.9)), Pose2D(0, 22, 0)),
    "west_aisle": (
        ((-14.9, -18.0), (-11.5, -18.0), (-11.5, 18.0), (-14.9, 18.0)),
        Pose2D(-13.2, 10.0, math.pi / 2),
    ),
    "east_aisle": (
        ((11.5, -18.0), (14.9, -18.0), (14.9, 18.0), (11.5, 18.0)),
        Pose2D(13.2, -10.0, math.pi / 2),
    ),
}


def _outer_walls(half_x: float, half_y: float) -> list[Box]:
    """Four walls whose inner faces are at |x| = half_x and |y| = half_y."""
    t = WALL_THICKNESS
    return [
        Box(0.0, half_y + t / 2, half_x + t, t / 2),
        Box(0.0, -half_y - t / 2, half_x + t, t / 2),
        Box(half_x + t / 2, 0.0, t / 2, half_y + t),
        Box(-half_x - t / 2, 0.0, t / 2, half_y + t),
    ]


def rack_boxes(x: float, y0: float, y1: float) -> list[Box]:
    """One pallet rack along y: the pallet row plus uprights proud of both faces."""
    core = RACK_DEPTH / 2.0 - UPRIGHT
    boxes = [Box(x, (y0 + y1) / 2.0, core, (y1 - y0) / 2.0)]
    bays = max(1, round((y1 - y0) / BAY))
    for k in range(bays + 1):
        y = y0 + UPRIGHT / 2 + k * (y1 - y0 - UPRIGHT) / bays
        for side in (-1.0, 1.0):
            boxes.append(Box(x + side * (core + UPRIGHT / 2), y, UPRIGHT / 2, UPRIGHT / 2))
    return boxes


def warehouse() -> World:
    """A 30 x 50 m warehouse: dock, two rack blocks with long aisles, cross aisle."""
    boxes = _outer_walls(_WH_X, _WH_Y)
    for y0, y1 in RACK_BLOCKS:
        for x in RACK_XS:
            boxes.extend(rack_boxes(x, y0, y1))
    boxes.extend(_rect(*extent) for extent in WAREHOUSE_PALLETS.values())
    boxes.extend(Box(x, y, 0.2, 0.2) for x, y in WAREHOUSE_COLUMNS)
    grid = rasterize(boxes, [], WAREHOUSE_BOUNDS, RESOLUTION, WAREHOUSE_SPAWN)
    rooms = {
        label: Room(label, polygon, anchor) for label, (polygon, anchor) in WAREHOUSE_ROOMS.items()
    }
    x0, x1, y0, y1 = WAREHOUSE_PALLETS["charger"]
    docks = _charger(x1 + DOCK_WALL_GAP, (y0 + y1) / 2.0, math.pi)
    return World("warehouse", boxes, [], grid, WAREHOUSE_SPAWN, rooms, docks=docks)


# --------------------------------------------------------------------------- depot

DEPOT_SPAWN = Pose2D(-12.0, 0.0, 0.0)
DEPOT_BOUNDS = (-15.5, 15.5, -8.0, 8.0)
_DEPOT_X, _DEPOT_Y = 15.0, 7.5
DEPOT_COLUMNS = tuple((x, y) for x in (-9.0, -3.0, 3.0, 9.0) for y in (-2.5, 2.5))
DEPOT_OBJECTS = {  # (xmin, xmax, ymin, ymax)
    "container": (4.0, 10.0, 5.0, 7.5),
    "pallets_sw": (-11.0, -8.6, -7.5, -6.3),
    "pallets_se": (7.0, 9.4, -7.5, -6.3),
    "shelf_east": (14.4, 15.0, -4.0, 0.5),
    "bin": (-1.0, -0.2, 6.7, 7.5),
}
DEPOT_ROOMS = {
    "west": (((-14.9, -7.4), (0.0, -7.4), (0.0, 7.4), (-14.9, 7.4)), Pose2D(-6.0, 0.0, 0.0)),
    "east": (((0.0, -7.4), (14.9, -7.4), (14.9, 4.9), (0.0, 4.9)), Pose2D(12.0, -4.5, 0.0)),
}


def depot() -> World:
    """An open 30 x 15 m depot with eight columns, a container and pallet stacks."""
    boxes = _outer_walls(_DEPOT_X, _DEPOT_Y)
    boxes.extend(Box(x, y, 0.2, 0.2) for x, y in DEPOT_COLUMNS)
    boxes.extend(_rect(*extent) for extent in DEPOT_OBJECTS.values())
    grid = rasterize(boxes, [], DEPOT_BOUNDS, RESOLUTION, DEPOT_SPAWN)
    rooms = {
        label: Room(label, polygon, anchor) for label, (polygon, anchor) in DEPOT_ROOMS.items()
    }
    docks = _charger(-13.0, -_DEPOT_Y + DOCK_WALL_GAP, -math.pi / 2.0)
    return World("depot", boxes, [], grid, DEPOT_SPAWN, rooms, docks=docks)


BUILTIN_WORLDS: dict[str, Callable[[], World]] = {
    "turtlebot3_world": turtlebot3_world,
    "small_house": small_house,
    "warehouse": warehouse,
    "depot": depot,
}
