"""A mission's ``zones:`` (keepout and speed zones, filter masks) on the costmap's grid."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from agv_mission.atomic import input_path
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.rooms import Room
from agv_mission.maps.ros_map import MapLoadError, load_ros_map
from agv_mission.maps.zones import FilterMask, ZoneFilters
from agv_mission.missions.load.problems import (
    ProblemLog,
    one_line,
    os_message,
)
from agv_mission.missions.load.schema import (
    Setup,
)
from agv_mission.missions.load.schema.zones import KeepoutMask, KeepoutZone, SpeedMask
from agv_mission.robots.description import (
    RobotDescription,
)


def zone_filters(
    mission: Setup,
    robot: RobotDescription,
    rooms: dict[str, Room],
    costmap: Costmap,
    base_dir: Path,
    log: ProblemLog,
) -> ZoneFilters | None:
    """The mission's ``zones:`` on the costmap's grid; each problem at its zone's field."""
    if not mission.zones:
        return None
    keepouts: list[Any] = []
    speeds: list[tuple[Any, float]] = []
    keepout_masks: list[FilterMask] = []
    speed_masks: list[tuple[FilterMask, bool]] = []
    for i, zone in enumerate(mission.zones):
        if isinstance(zone, KeepoutMask | SpeedMask):
            path = input_path(zone.map.strip(), base_dir)  # the path guard saw it first
            try:
                mask = FilterMask(load_ros_map(path), zone.base, zone.multiplier)
            except MapLoadError as exc:
                log.add(("zones", i, "map"), one_line(str(exc)))
                continue
            except (OSError, ValueError, RuntimeError) as exc:
                log.add(("zones", i, "map"), f"cannot read mask {zone.map!r}: {os_message(exc)}")
                continue
            except MemoryError:
                log.add(("zones", i, "map"), f"mask {zone.map!r} is too large for memory")
                continue
            if isinstance(zone, KeepoutMask):
                keepout_masks.append(mask)
            else:
                speed_masks.append((mask, zone.unit == "percent"))
            continue
        if zone.room is not None:
            room = rooms.get(zone.room)
            if room is None:
                known = ", ".join(sorted(rooms)) or "none"
                log.add(("zones", i, "room"), f"no room {zone.room!r} (rooms: {known})")
                continue
            polygon = room.polygon
        else:
            polygon = tuple((p[0], p[1]) for p in zone.polygon or ())
        if isinstance(zone, KeepoutZone):
            keepouts.append(polygon)
        else:
            limit = zone.max_speed
            if limit is None:
                limit = (zone.percent or 100.0) / 100.0 * robot.max_linear_velocity
            speeds.append((polygon, limit))
    log.raise_if_any()
    return ZoneFilters.build(
        costmap, robot.max_linear_velocity, keepouts, speeds, keepout_masks, speed_masks
    )
