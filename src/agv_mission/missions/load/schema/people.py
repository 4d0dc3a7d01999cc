"""``people:``: simulated pedestrians who wander in an area or walk a route
(people-and-zones.md)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import AfterValidator, Field, model_validator
from shapely import Polygon

from agv_mission.missions.load.schema.base import MAX_SIM_SECONDS, StrictModel

# Bounds (each person is an ORCA agent and a body of the world: memory and time scale
# with them). 200 people cost about 4x the 50 the benchmarks measure.
MAX_PEOPLE = 200  # in all the mission's entries together
MAX_PEOPLE_GROUPS = 50
MAX_ROUTE_POINTS = 100
MAX_AREA_POINTS = 1000
MAX_PERSON_SPEED = 3.0  # m/s: a brisk run; walking is 1.2-1.5 (Weidmann 1993: 1.34)
MAX_PERSON_RADIUS = 1.0  # m

Point = Annotated[list[float], Field(min_length=2, max_length=2, description="[x, y], m")]


class RoutePoint(StrictModel):
    """A point of a route in the map frame."""

    x: float = Field(description="m, map frame")
    y: float = Field(description="m, map frame")


class PeopleSpec(StrictModel):
    """``count`` people who wander inside ``area`` (a room label or a polygon) or walk
    ``route`` round and round, at ``speed``, from ``start_time`` on."""

    count: int = Field(1, ge=1, le=MAX_PEOPLE, description="how many people of this kind")
    area: str | list[Point] | None = Field(
        None, description="wander: a room label or a polygon [[x, y], ...] in the map frame"
    )
    behaviour: Literal["wander", "route"] = Field(
        "wander", description="wander: to random goals inside `area`; route: along `route`"
    )
    route: list[RoutePoint] | None = Field(
        None,
        min_length=2,
        max_length=MAX_ROUTE_POINTS,
        description="route: points walked in order, back to the first and round again",
    )
    speed: float = Field(
        1.2, gt=0.0, le=MAX_PERSON_SPEED, description="preferred walking speed, m/s"
    )
    radius: float = Field(
        0.25, gt=0.0, le=MAX_PERSON_RADIUS, description="the body's radius (half shoulder width), m"
    )
    start_time: float = Field(
        0.0, ge=0.0, le=MAX_SIM_SECONDS, description="simulated s; absent from the world before"
    )

    attentive: bool = Field(
        True,
        description="false: walks its way as if nobody were there (a distracted pedestrian "
        "stepping out in front of a robot); others still avoid them",
    )

    @model_validator(mode="after")
    def _behaviour_needs(self) -> PeopleSpec:
        if self.behaviour == "wander":
            if self.area is None:
                raise ValueError("people who wander need an `area` (a room label or a polygon)")
            if self.route is not None:
                raise ValueError("`route` is for behaviour: route (these people wander)")
            if isinstance(self.area, list):
                if not 3 <= len(self.area) <= MAX_AREA_POINTS:
                    raise ValueError(f"an area polygon has 3 to {MAX_AREA_POINTS} points")
                shape = Polygon([tuple(p) for p in self.area])
                if not shape.is_valid or shape.area <= 0.0:
                    raise ValueError(
                        "area polygon must be simple (no crossing edges) with a non-zero area"
                    )
        else:
            if self.route is None:
                raise ValueError("people on a route need `route` (at least two points)")
            if self.area is not None:
                raise ValueError("`area` is for behaviour: wander (these people walk a route)")
        return self


def _at_most_max_people(groups: list[PeopleSpec]) -> list[PeopleSpec]:
    total = sum(g.count for g in groups)
    if total > MAX_PEOPLE:
        raise ValueError(f"{total} people in all: at most {MAX_PEOPLE}")
    return groups


People = Annotated[
    list[PeopleSpec],
    Field(
        max_length=MAX_PEOPLE_GROUPS,
        description="simulated people: bodies the lidar sees, walking with ORCA",
    ),
    AfterValidator(_at_most_max_people),
]
