"""The ports of the condition nodes (:mod:`agv_mission.behaviors.conditions`, the battery's
in :mod:`agv_mission.behaviors.battery`)."""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

from pydantic import (
    Field,
    field_validator,
    model_validator,
)

from agv_mission.behaviors.ports.node import ConditionPorts, entry_port
from agv_mission.behaviors.ports.values import FieldPath, Goal


class InRoomPorts(ConditionPorts):
    """The estimated position lies inside the room's polygon."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:InRoomCondition"
    type: Literal["in_room"]
    example: ClassVar[dict[str, Any] | None] = {"room": "room"}
    room: str = Field(min_length=1, description="a room label")

    def rooms_named(self) -> list[tuple[FieldPath, str]]:
        return [(("room",), self.room)]


class AtPosePorts(ConditionPorts):
    """The estimated position is within ``tolerance`` of ``pose``."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:AtPose"
    type: Literal["at_pose"]
    example: ClassVar[dict[str, Any] | None] = {"pose": {"x": 1.0, "y": 1.0}}
    pose: Goal = Field(description="a pose or a room label")
    tolerance: float = Field(0.25, gt=0.0, description="m")


class RangeAheadBelowPorts(ConditionPorts):
    """The nearest lidar return within ``fov`` of straight ahead is closer than ``distance``
    (the seed's ``range_ahead``)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:RangeAheadBelow"
    type: Literal["range_ahead_below"]
    example: ClassVar[dict[str, Any] | None] = {"distance": 0.5}
    distance: float = Field(gt=0.0, description="m")
    fov: float = Field(0.35, gt=0.0, le=math.pi, description="the cone's half-width, rad")


class PersonNearPorts(ConditionPorts):
    """A person's edge is within ``distance`` of the robot's footprint (the people the run
    tracks, as ``metrics.people`` measures them)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:PersonNear"
    type: Literal["person_near"]
    example: ClassVar[dict[str, Any] | None] = {"distance": 1.0}
    distance: float = Field(gt=0.0, description="m")


class IsBatteryLowPorts(ConditionPorts):
    """The battery's level is at or below ``min_battery`` (Nav2's IsBatteryLow); fails
    without a battery."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:IsBatteryLow"
    type: Literal["is_battery_low"]
    example: ClassVar[dict[str, Any] | None] = {"min_battery": 0.3}
    min_battery: float = Field(ge=0.0, le=1.0, description="battery level, 0..1")
    battery_topic: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")
    is_voltage: bool = Field(False, description="Nav2's: min_battery is a voltage (refused)")

    @field_validator("is_voltage")
    @classmethod
    def _level(cls, v: bool) -> bool:
        if v:
            raise ValueError("the battery model gives a level, not a voltage")
        return v


class IsBatteryChargingPorts(ConditionPorts):
    """The robot is docked and charging."""

    plugin: ClassVar[str] = "agv_mission.behaviors.battery:IsBatteryCharging"
    type: Literal["is_battery_charging"]
    example: ClassVar[dict[str, Any] | None] = {}
    battery_topic: Any = Field(None, description="ROS plumbing (Nav2): accepted and ignored")


class TimeElapsedPorts(ConditionPorts):
    """At least ``seconds`` of simulated time have passed since the mission started."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:TimeElapsed"
    type: Literal["time_elapsed"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.0}
    seconds: float = Field(ge=0.0, description="simulated seconds")


class CheckBlackboardPorts(ConditionPorts):
    """Blackboard entry ``key`` equals, is less than or greater than a value."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:CheckBlackboard"
    type: Literal["check_blackboard"]
    example: ClassVar[dict[str, Any] | None] = {"key": "k", "equals": 1}
    key: str = entry_port("the entry read (a name, or {name})")
    equals: Any = Field(None, description="succeed when the entry equals this")
    less: float | None = Field(None, description="succeed when the entry is below this")
    greater: float | None = Field(None, description="succeed when the entry is above this")

    @model_validator(mode="after")
    def _one_test(self) -> CheckBlackboardPorts:
        given = [k for k in ("equals", "less", "greater") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError("give exactly one of equals, less, greater")
        return self


class IsPathClearPorts(ConditionPorts):
    """A plan to ``goal`` exists on the current costmap (lidar obstacles included)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.conditions:IsPathClear"
    type: Literal["is_path_clear"]
    example: ClassVar[dict[str, Any] | None] = {"goal": {"x": 3.0, "y": 3.0}}
    goal: Goal = Field(description="a pose or a room label")
