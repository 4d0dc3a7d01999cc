"""The ``tasks`` of a mission: what the robot does, one discriminated union by ``type``."""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field, field_validator, model_validator

from agv_mission.geometry import Bounds
from agv_mission.missions.schema.base import (
    MAX_LOOPS,
    MAX_ROOMS,
    MAX_SIM_SECONDS,
    MAX_WAYPOINTS,
    Pose,
    StrictModel,
)


class FailurePolicy(StrictModel):
    """What a failed goal does to its task (patrol: to each waypoint; visit_rooms: each room)."""

    on_failure: Literal["abort", "skip", "retry"] = Field(
        "abort",
        description="abort: the mission fails; skip: record the failure and go on; "
        "retry: try again `retries` times, then abort",
    )
    retries: int = Field(1, ge=1, description="extra attempts with on_failure: retry")


class GoToTask(FailurePolicy):
    """Navigate to one pose."""

    type: Literal["go_to"]
    pose: Pose


class PatrolTask(FailurePolicy):
    """Visit the waypoints in order, ``loops`` times, waiting ``dwell`` seconds at each."""

    type: Literal["patrol"]
    waypoints: list[Pose] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    loops: int = Field(1, ge=1, le=MAX_LOOPS, description="rounds; each is built when it starts")
    dwell: float = Field(
        0.0, ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds at each waypoint"
    )


class WanderTask(StrictModel):
    """Drive ahead while the range ahead exceeds ``min_range``, turn otherwise (seed ex. 7.3)."""

    type: Literal["wander"]
    duration: float = Field(gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")
    min_range: float = Field(0.8, gt=0.0, description="metres")
    speed: float | None = Field(None, gt=0.0, description="m/s; default: the robot's maximum")
    turn_rate: float = Field(0.4, gt=0.0, description="rad/s while turning")
    sector: float = Field(
        20.0, gt=0.0, le=180.0, description="half-width of the 'ahead' sector, degrees"
    )


class SettleBeforeRecording(StrictModel):
    """Tasks that record a pose let the localiser settle first."""

    settle: float = Field(
        1.0,
        ge=0.0,
        description="seconds standing still before recording, localisation updating on "
        "every scan (amcl's request_nomotion_update)",
    )


class VisitRoomsTask(FailurePolicy, SettleBeforeRecording):
    """Go into each room in order (its anchor, or a free point well inside it)."""

    type: Literal["visit_rooms"]
    rooms: list[str] = Field(
        min_length=1, max_length=MAX_ROOMS, description="room labels, visited in this order"
    )
    record: bool = Field(False, description="record the estimated pose in each room")


class RecordRoomTask(SettleBeforeRecording):
    """Record the current estimated pose under a label (the seed's room_service call)."""

    type: Literal["record_room"]
    room: str = Field(min_length=1, description="the label to record under")


class AreaBounds(StrictModel):
    """An axis-aligned rectangle of the map frame, metres."""

    xmin: float
    xmax: float
    ymin: float
    ymax: float

    @model_validator(mode="after")
    def _ordered(self) -> AreaBounds:
        if self.xmax <= self.xmin or self.ymax <= self.ymin:
            raise ValueError("bounds need xmin < xmax and ymin < ymax")
        return self

    def as_tuple(self) -> Bounds:
        return (self.xmin, self.xmax, self.ymin, self.ymax)


class MapAreaTask(StrictModel):
    """Explore ``bounds`` by frontiers while SLAM builds the map; save it map_saver-style.

    Later tasks of the mission navigate (and localise) on the saved map.
    """

    type: Literal["map_area"]
    bounds: AreaBounds | None = Field(None, description="default: the whole world map")
    save_map: str = Field("map", description="writes <save_map>.pgm + .yaml in the run directory")
    coverage: float | None = Field(
        None, gt=0.0, le=1.0, description="stop once this share of the bounds is known"
    )
    time_limit: float | None = Field(
        None, gt=0.0, le=MAX_SIM_SECONDS, description="stop after this many seconds"
    )
    min_frontier_size: int = Field(8, ge=1, description="smallest frontier worth a visit, cells")

    @field_validator("save_map")
    @classmethod
    def _stem(cls, v: str) -> str:
        if not v.strip() or "/" in v or "\\" in v or v in (".", ".."):
            raise ValueError("save_map is a file name stem without path separators")
        return v


class TeleopTask(StrictModel):
    """Hold the robot under remote command (the service's live stream sends cmd_vel).

    The robot stops when no command arrived for 0.5 s of wall time; under the service,
    simulated time runs at wall-clock speed during this task.
    """

    type: Literal["teleop"]
    duration: float | None = Field(
        None, gt=0.0, description="simulated seconds; None: until the run is cancelled"
    )


class DockTask(StrictModel):
    """Drive to the dock's staging pose, then straight and slowly onto the dock."""

    type: Literal["dock"]
    dock: str = Field("charger", min_length=1, description="a dock of the world or rooms file")


class UndockTask(StrictModel):
    """Back out of the dock to its staging pose."""

    type: Literal["undock"]


class ChargeTask(StrictModel):
    """Charge on the dock (the robot must be docked) until the level reaches ``until``."""

    type: Literal["charge"]
    until: float = Field(1.0, gt=0.0, le=1.0, description="battery level to charge to, 0..1")


Task = Annotated[
    Union[  # noqa: UP007
        GoToTask,
        PatrolTask,
        WanderTask,
        VisitRoomsTask,
        RecordRoomTask,
        MapAreaTask,
        TeleopTask,
        DockTask,
        UndockTask,
        ChargeTask,
    ],
    Field(discriminator="type"),
]
