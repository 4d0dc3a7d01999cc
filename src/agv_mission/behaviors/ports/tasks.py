"""The task types of ``mission-format.md``: action nodes like any other, whose port models
are the task models; what is checked of them against the map and reported of them in
``result.json`` is written here, beside their ports."""

from __future__ import annotations

from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import (
    Field,
    field_validator,
)

from agv_mission.behaviors.ports.node import NodePorts
from agv_mission.behaviors.ports.values import (
    MAX_LOOPS,
    MAX_ROOMS,
    MAX_SIM_SECONDS,
    MAX_WAYPOINTS,
    AreaBounds,
    FieldPath,
    Pose,
    StrictModel,
)

_OUTCOMES = {"goal_reached": "reached", "goal_failed": "failed", "goal_skipped": "skipped"}


class FailurePolicy(StrictModel):
    """What a failed goal does to its task (patrol: to each waypoint; visit_rooms: each room)."""

    on_failure: Literal["abort", "skip", "retry"] = Field(
        "abort",
        description="abort: the mission fails; skip: record the failure and go on; "
        "retry: try again `retries` times, then abort",
    )
    retries: int = Field(1, ge=1, description="extra attempts with on_failure: retry")


class TaskPorts(NodePorts):
    task: ClassVar[bool] = True


class GoToTask(TaskPorts, FailurePolicy):
    """Navigate to one pose."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:GoTo"
    type: Literal["go_to"]
    example: ClassVar[dict[str, Any] | None] = {"pose": {"x": 2.0, "y": 2.0}}
    pose: Pose

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        return [(("pose",), self.pose)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        if out["status"] == "partial":
            out["status"] = "skipped"
        return out


class PatrolTask(TaskPorts, FailurePolicy):
    """Visit the waypoints in order, ``loops`` times, waiting ``dwell`` seconds at each."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:Patrol"
    type: Literal["patrol"]
    example: ClassVar[dict[str, Any] | None] = {"waypoints": [{"x": 2.0, "y": 1.0}]}
    waypoints: list[Pose] = Field(min_length=1, max_length=MAX_WAYPOINTS)
    loops: int = Field(1, ge=1, le=MAX_LOOPS, description="rounds; each is built when it starts")
    dwell: float = Field(
        0.0, ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds at each waypoint"
    )

    def goal_poses(self) -> list[tuple[FieldPath, Pose]]:
        return [(("waypoints", j), wp) for j, wp in enumerate(self.waypoints)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        out["waypoints_planned"] = self.loops * len(self.waypoints)
        out["waypoints"] = [
            {k: e[k] for k in ("loop", "waypoint", "t", "x", "y", "yaw", "reason") if k in e}
            | {"status": _OUTCOMES[e["event"]]}
            for e in events
            if e["event"] in _OUTCOMES
        ]
        return out


class WanderTask(TaskPorts):
    """Drive ahead while the range ahead exceeds ``min_range``, turn otherwise (seed ex. 7.3)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:WanderTaskNode"
    type: Literal["wander"]
    example: ClassVar[dict[str, Any] | None] = {"duration": 1.0}
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


class VisitRoomsTask(TaskPorts, FailurePolicy, SettleBeforeRecording):
    """Go into each room in order (its anchor, or a free point well inside it)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:VisitRooms"
    type: Literal["visit_rooms"]
    example: ClassVar[dict[str, Any] | None] = {"rooms": ["room"]}
    rooms: list[str] = Field(
        min_length=1, max_length=MAX_ROOMS, description="room labels, visited in this order"
    )
    record: bool = Field(False, description="record the estimated pose in each room")

    def rooms_visited(self) -> list[tuple[FieldPath, str]]:
        return [(("rooms", j), room) for j, room in enumerate(self.rooms)]

    def report(self, status: str, events: list[dict[str, Any]]) -> dict[str, Any]:
        out = super().report(status, events)
        out["rooms"] = [_room_report(room, events) for room in self.rooms]
        return out


def _room_report(room: str, events: list[dict[str, Any]]) -> dict[str, Any]:
    outcome = next(
        (
            e
            for e in events
            if e.get("room") == room and e["event"] in ("goal_failed", "goal_skipped")
        ),
        None,
    )
    reached = any(e["event"] == "goal_reached" and e.get("room") == room for e in events)
    report: dict[str, Any] = {
        "room": room,
        "status": _OUTCOMES[outcome["event"]] if outcome else ("reached" if reached else "not_run"),
        "recorded": any(e["event"] == "room_recorded" and e.get("room") == room for e in events),
    }
    if outcome:
        report["reason"] = outcome["reason"]
    return report


class RecordRoomTask(TaskPorts, SettleBeforeRecording):
    """Record the current estimated pose under a label (the seed's room_service call)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:RecordRoomTaskNode"
    type: Literal["record_room"]
    example: ClassVar[dict[str, Any] | None] = {"room": "room"}
    room: str = Field(min_length=1, description="the label to record under")


class MapAreaTask(TaskPorts):
    """Explore ``bounds`` by frontiers while SLAM builds the map; save it map_saver-style.

    Later tasks of the mission navigate (and localise) on the saved map.
    """

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:MapAreaTaskNode"
    type: Literal["map_area"]
    example: ClassVar[dict[str, Any] | None] = None
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

    def map_bounds(self) -> list[tuple[FieldPath, AreaBounds | None]]:
        return [(("bounds",), self.bounds)]


class TeleopTask(TaskPorts):
    """Hold the robot under remote command (the service's live stream sends cmd_vel).

    The robot stops when no command arrived for 0.5 s of wall time; under the service,
    simulated time runs at wall-clock speed during this task.
    """

    plugin: ClassVar[str] = "agv_mission.behaviors.tasks:Teleop"
    type: Literal["teleop"]
    example: ClassVar[dict[str, Any] | None] = {"duration": 0.5}
    duration: float | None = Field(
        None, gt=0.0, description="simulated seconds; None: until the run is cancelled"
    )


class DockTask(TaskPorts):
    """Drive to the dock's staging pose, then straight and slowly onto the dock."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Dock"
    type: Literal["dock"]
    example: ClassVar[dict[str, Any] | None] = None
    dock: str = Field("charger", min_length=1, description="a dock of the world or rooms file")


class UndockTask(TaskPorts):
    """Back out of the dock to its staging pose."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Undock"
    type: Literal["undock"]
    example: ClassVar[dict[str, Any] | None] = None


class ChargeTask(TaskPorts):
    """Charge on the dock (the robot must be docked) until the level reaches ``until``."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:Charge"
    type: Literal["charge"]
    example: ClassVar[dict[str, Any] | None] = None
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
