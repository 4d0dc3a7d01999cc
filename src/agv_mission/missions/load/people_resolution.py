"""The mission's ``people:`` checked against its map and rooms and resolved to the map
frame: each problem is reported at its field (``people.2.route.1``), as the world checks do.

A user picks route points by eye: a point on free space too near a wall for the person is
walked to as near as the person fits (the nearest point with room for them), with a warning
at its field; only a point inside a wall or unknown space, or off the map, is invalid."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import shapely

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.missions.load.schema.people import PeopleSpec
from agv_mission.missions.load.yaml_lines import FieldPath
from agv_mission.world.people_groups import PeopleGroup
from agv_mission.world.walkable import clearance
from agv_mission.world.walking_routes import RouteGrid, route_grid

Report = Callable[[FieldPath, str], None]


def _ignore(_field: FieldPath, _message: str) -> None:
    """A warning nobody asked to hear."""


def resolve_people(
    specs: Sequence[PeopleSpec],
    rooms: dict[str, Room],
    grid: OccupancyGrid,
    report: Report,
    warn: Report = _ignore,
) -> list[PeopleGroup]:
    """The groups a ``Crowd`` is built from; every problem goes to ``report`` (a group with
    one is left out, so the caller raises them together), every point moved to where the
    person fits to ``warn``."""
    if not specs:
        return []
    room_left = clearance(grid)
    groups: list[PeopleGroup] = []
    for i, spec in enumerate(specs):
        where: FieldPath = ("people", i)
        router = route_grid(grid, spec.radius)
        ok = True
        area: tuple[tuple[float, float], ...] = ()
        route: tuple[tuple[float, float], ...] = ()
        if spec.behaviour == "wander":
            area, ok = _area(spec, rooms, router, report, warn, where)
        else:
            route, ok = _route(spec, grid, room_left, router, report, warn, where)
        if ok:
            groups.append(
                PeopleGroup(
                    count=spec.count,
                    behaviour=spec.behaviour,
                    area=area,
                    route=route,
                    speed=spec.speed,
                    radius=spec.radius,
                    start_time=spec.start_time,
                    attentive=spec.attentive,
                )
            )
    return groups


def _area(
    spec: PeopleSpec,
    rooms: dict[str, Room],
    router: RouteGrid,
    report: Report,
    warn: Report,
    where: FieldPath,
) -> tuple[tuple[tuple[float, float], ...], bool]:
    """The wander area's polygon, checked to hold its people on free space; an area too
    near the walls for them grows (a little, with a warning) to where they fit."""
    if isinstance(spec.area, str):
        room = rooms.get(spec.area)
        if room is None:
            known = ", ".join(sorted(rooms)) or "none"
            report((*where, "area"), f"no room {spec.area!r} (rooms: {known})")
            return (), False
        polygon = tuple((float(x), float(y)) for x, y in room.polygon)
        name = f"room {spec.area!r}"
    else:
        polygon = tuple((float(p[0]), float(p[1])) for p in spec.area or ())
        name = "the area"
    walkable = float(len(router.cells_within(polygon))) * router.cell_area
    needed = spec.count * (2 * spec.radius) ** 2
    if walkable <= 0.0 or needed > walkable:
        grown = _grown(polygon, router, needed)
        if grown is None and walkable <= 0.0:
            report(
                (*where, "area"),
                f"{name} has no free space a person of radius {spec.radius:g} m can walk in",
            )
            return (), False
        if grown is None:
            report(
                (*where, "count"),
                f"{spec.count} people of radius {spec.radius:g} m do not fit in {name} "
                f"({walkable:.1f} m² of it is walkable)",
            )
            return (), False
        polygon, margin = grown
        warn(
            (*where, "area"),
            f"{name} has {walkable:.1f} m² where {spec.count} people of radius "
            f"{spec.radius:g} m walk: they walk as near as they fit, within {margin:g} m "
            "of it",
        )
    return polygon, True


def _route(
    spec: PeopleSpec,
    grid: OccupancyGrid,
    room_left: np.ndarray,
    router: RouteGrid,
    report: Report,
    warn: Report,
    where: FieldPath,
) -> tuple[tuple[tuple[float, float], ...], bool]:
    """The route's points, each on free space with room for the person (moved there when
    too near a wall), all joined."""
    points = list((p.x, p.y) for p in spec.route or ())
    ok = True
    pieces: list[int | None] = []
    for j, (x, y) in enumerate(points):
        field = (*where, "route", j)
        rows, cols = grid.world_to_cell(np.array([x, y]))
        if not bool(grid.in_bounds(rows, cols)):
            report(field, f"({x:g}, {y:g}) is off the map")
            ok = False
            pieces.append(None)
            continue
        room = float(room_left[int(rows), int(cols)])
        if room < 0:
            report(
                field,
                f"({x:g}, {y:g}) is in a wall or unknown space: a person cannot walk there",
            )
            ok = False
            pieces.append(None)
            continue
        if room < spec.radius:
            near = nearest_fit(grid, room_left, (x, y), spec.radius)
            if near is None:
                report(field, f"({x:g}, {y:g}): a person of radius {spec.radius:g} m fits nowhere")
                ok = False
                pieces.append(None)
                continue
            warn(
                field,
                f"({x:g}, {y:g}) is {room:.2f} m from a wall, too near for a person of radius "
                f"{spec.radius:g} m: they walk to ({near[0]:.2f}, {near[1]:.2f}) instead, "
                f"{np.hypot(near[0] - x, near[1] - y):.2f} m away, as near as they fit",
            )
            x, y = points[j] = near
        node = router.node((x, y))
        pieces.append(None if node is None else router.component(node))
    if ok:
        first = pieces[0]
        for j, piece in enumerate(pieces[1:], start=1):
            if piece != first:
                x, y = points[j]
                report(
                    (*where, "route", j),
                    f"({x:g}, {y:g}) cannot be walked to from the route's first point "
                    f"({points[0][0]:g}, {points[0][1]:g}): walls are in the way",
                )
                ok = False
    return tuple(points), ok


#: m an area grows by, step by step, to hold its people (at most the last)
AREA_GROWTH = (0.25, 0.5, 1.0)


def _grown(
    polygon: tuple[tuple[float, float], ...], router: RouteGrid, needed: float
) -> tuple[tuple[tuple[float, float], ...], float] | None:
    """``polygon`` grown by the least of :data:`AREA_GROWTH` that holds ``needed`` m² of
    walkable space, and by how much; None when none does."""
    for margin in AREA_GROWTH:
        shape = shapely.Polygon(polygon).buffer(margin, join_style="mitre")
        if not isinstance(shape, shapely.Polygon) or shape.is_empty:
            return None
        ring = tuple((float(x), float(y)) for x, y in shape.exterior.coords[:-1])
        if float(len(router.cells_within(ring))) * router.cell_area >= max(needed, 1e-9):
            return ring, margin
    return None


def nearest_fit(
    grid: OccupancyGrid, room_left: np.ndarray, xy: tuple[float, float], radius: float
) -> tuple[float, float] | None:
    """The map point nearest ``xy`` where a person of ``radius`` fits (a cell whose room to
    the nearest wall is at least the radius and half a cell more), or None."""
    fits = np.argwhere(room_left >= radius + grid.resolution / 2)
    if fits.size == 0:
        return None
    centres = grid.cell_to_world(fits[:, 0], fits[:, 1])
    gap = np.hypot(centres[:, 0] - xy[0], centres[:, 1] - xy[1])
    best = centres[int(np.argmin(gap))]
    return float(best[0]), float(best[1])
