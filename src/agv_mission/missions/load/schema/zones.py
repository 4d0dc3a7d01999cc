"""``zones:``: keepout and speed-limit areas, as polygons, rooms or Nav2 filter masks
(people-and-zones.md)."""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field, model_validator
from shapely import Polygon

from agv_mission.missions.load.schema.base import StrictModel

MAX_ZONES = 100
MAX_POLYGON_POINTS = 1000

Point = Annotated[list[float], Field(min_length=2, max_length=2, description="[x, y], m")]


class _Area(StrictModel):
    """An area given as a polygon (map frame, m) or a room label, not both."""

    polygon: list[Point] | None = Field(
        None, min_length=3, max_length=MAX_POLYGON_POINTS, description="[[x, y], ...], m"
    )
    room: str | None = Field(None, description="a room label: the room's polygon")

    @model_validator(mode="after")
    def _polygon_or_room(self) -> _Area:
        if (self.polygon is None) == (self.room is None):
            raise ValueError("a zone has a `polygon` or a `room`, not both")
        if self.polygon is not None:
            shape = Polygon([tuple(p) for p in self.polygon])
            if not shape.is_valid or shape.area <= 0.0:
                raise ValueError("polygon must be simple (no crossing edges) with a non-zero area")
        return self


class KeepoutZone(_Area):
    """Lethal for every planner and for the controller (Nav2's keepout filter)."""

    type: Literal["keepout"]


class SpeedLimitZone(_Area):
    """Caps the commanded speed while the footprint overlaps it (Nav2's speed filter)."""

    type: Literal["speed_limit"]
    max_speed: float | None = Field(None, gt=0.0, description="m/s")
    percent: float | None = Field(
        None, gt=0.0, le=100.0, description="of the robot's maximum linear speed"
    )

    @model_validator(mode="after")
    def _one_limit(self) -> SpeedLimitZone:
        if (self.max_speed is None) == (self.percent is None):
            raise ValueError("a speed_limit zone has `max_speed` (m/s) or `percent`, not both")
        return self


class KeepoutMask(StrictModel):
    """A Nav2 keepout filter mask: a map_server YAML; filter value = base + multiplier *
    mask value (``CostmapFilterInfo``), cells of value >= 65 (map_server's occupied
    threshold, in percent) are kept out of."""

    type: Literal["keepout_mask"]
    map: str = Field(description="a map_server YAML (image, resolution, origin, mode)")
    base: float = 0.0
    multiplier: float = 1.0


class SpeedMask(StrictModel):
    """A Nav2 speed filter mask: limit = base + multiplier * mask value where the mask value
    is neither 0 nor unknown (Nav2: no limit there); ``unit: percent`` of the robot's
    maximum speed (``CostmapFilterInfo`` type 1) or ``m/s`` (type 2)."""

    type: Literal["speed_mask"]
    map: str = Field(description="a map_server YAML (image, resolution, origin, mode)")
    base: float = 0.0
    multiplier: float = 1.0
    unit: Literal["percent", "m/s"] = "percent"


Zone = Annotated[
    Union[KeepoutZone, SpeedLimitZone, KeepoutMask, SpeedMask],  # noqa: UP007
    Field(discriminator="type"),
]
