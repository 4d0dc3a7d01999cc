"""The mission's ``people:`` checked against its map and rooms and resolved to the map
frame: each problem is reported at its field (``people.2.route.1``), as the world checks do."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.missions.schema.people import PeopleSpec
from agv_mission.missions.yaml_lines import FieldPath
from agv_mission.world.crowd import PeopleGroup, RouteGrid, clearance, route_grid

Report = Callable[[FieldPath, str], None]


def resolve_people(
    specs: Sequence[PeopleSpec], rooms: dict[str, Room], grid: OccupancyGrid, report: Report
) -> list[PeopleGroup]:
    """The groups a ``Crowd`` is built from; every problem goes to ``report`` (a group with
    one is left out, so the caller raises them together)."""
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
            area, ok = _area(spec, rooms, router, report, where)
        else:
            route, ok = _route(spec, grid, room_left, router, report, where)
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
    where: FieldPath,
) -> tuple[tuple[tuple[float, float], ...], bool]:
    """The wander area's polygon, checked to hold its people on free space."""
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
    if walkable <= 0.0:
        report(
            (*where, "area"),
            f"{name} has no free space a person of radius {spec.radius:g} m can walk in",
        )
        return (), False
    needed = spec.count * (2 * spec.radius) ** 2
    if needed > walkable:
        report(
            (*where, "count"),
            f"{spec.count} people of radius {spec.radius:g} m do not fit in {name} "
            f"({walkable:.1f} m² of it is walkable)",
        )
        return (), False
    return polygon, True


def _route(
    spec: PeopleSpec,
    grid: OccupancyGrid,
    room_left: np.ndarray,
    router: RouteGrid,
    report: Report,
    where: FieldPath,
) -> tuple[tuple[tuple[float, float], ...], bool]:
    """The route's points, each on free space with room for the person, all joined."""
    points = tuple((p.x, p.y) for p in spec.route or ())
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
        if room < spec.radius:
            what = (
                "in a wall or unknown space" if room < 0 else f"{max(room, 0.0):.2f} m from a wall"
            )
            report(
                field,
                f"({x:g}, {y:g}) is {what}: a person of radius {spec.radius:g} m does not fit",
            )
            ok = False
            pieces.append(None)
            continue
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
    return points, ok
