"""What a port carries: poses (planar or ROS style), areas, a blackboard entry's name, the
strict model every port model builds on, and the bounds on what scales memory or time."""

from __future__ import annotations

import math
import re
from typing import Any, Union

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    GetJsonSchemaHandler,
    model_validator,
)
from pydantic.json_schema import JsonSchemaValue
from pydantic_core import CoreSchema, InitErrorDetails, PydanticCustomError, ValidationError

from agv_mission.geometry import Bounds, Pose2D, yaw_from_quaternion

QUATERNION_TOLERANCE = 1e-3
MAX_WAYPOINTS = 10_000
MAX_LOOPS = 1_000_000
MAX_ROOMS = 1000
MAX_SIM_SECONDS = 86_400.0  # one simulated day


FieldPath = tuple[str | int, ...]


#: A port value that names a blackboard entry (BT.CPP's convention).
BLACKBOARD_REF = re.compile(r"^\{([A-Za-z_][\w.#/-]*)\}$")


def blackboard_key(value: Any) -> str | None:
    """The entry ``"{key}"`` names, or None for a literal."""
    if isinstance(value, str):
        m = BLACKBOARD_REF.match(value)
        if m:
            return m.group(1)
    return None


class StrictModel(BaseModel):
    # defer_build: a model's validator is built when first used, not on import (the models
    # of input files do so throughout): a process builds those of what it reads, once each.
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)


class Position(StrictModel):
    x: float
    y: float
    z: float = 0.0


class Orientation(StrictModel):
    x: float = 0.0
    y: float = 0.0
    z: float
    w: float


class Pose(StrictModel):
    """A planar pose: ``{x, y, yaw}`` or ROS style ``{position: {...}, orientation: {...}}``."""

    x: float = Field(description="metres, map frame")
    y: float = Field(description="metres, map frame")
    yaw: float = Field(0.0, description="radians, counter-clockwise from +x")

    @model_validator(mode="before")
    @classmethod
    def _from_ros(cls, data: Any) -> Any:
        if not isinstance(data, dict) or ("position" not in data and "orientation" not in data):
            return data
        extra = set(data) - {"position", "orientation"}
        if extra:
            raise ValueError(
                f"a ROS-style pose has only 'position' and 'orientation', not {sorted(extra, key=str)}"
            )
        for key in ("position", "orientation"):
            if key not in data:  # geometry_msgs/Pose has both: no silent (0, 0) or yaw 0
                raise _nested_error(
                    key,
                    PydanticCustomError(
                        "ros_pose_incomplete",
                        "a ROS-style pose needs both 'position' and 'orientation'",
                    ),
                    data,
                )
        details: list[InitErrorDetails] = []
        position = _validate_part(Position, "position", data["position"], details)
        q = _validate_part(Orientation, "orientation", data["orientation"], details)
        if details:
            raise ValidationError.from_exception_data("Pose", details)
        norm = math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2)
        if abs(norm - 1.0) > QUATERNION_TOLERANCE:
            raise ValueError(
                f"orientation quaternion has length {norm:.6f}; expected unit length (within 1e-3)"
            )
        if abs(q.x) > QUATERNION_TOLERANCE or abs(q.y) > QUATERNION_TOLERANCE:
            raise ValueError(
                "orientation tilts out of the plane (x and y must be 0 for a planar robot)"
            )
        return {"x": position.x, "y": position.y, "yaw": yaw_from_quaternion(q.x, q.y, q.z, q.w)}

    def to_pose2d(self) -> Pose2D:
        return Pose2D(self.x, self.y, self.yaw)

    @classmethod
    def __get_pydantic_json_schema__(
        cls, core_schema: CoreSchema, handler: GetJsonSchemaHandler
    ) -> JsonSchemaValue:
        """Either spelling, as the validator takes them (the quaternion's unit length and
        planarity are checks the schema cannot express)."""
        schema = handler.resolve_ref_schema(handler(core_schema))
        planar = {
            k: schema.pop(k)
            for k in ("type", "properties", "required", "additionalProperties")
            if k in schema
        }
        schema["anyOf"] = [planar, ROS_POSE_SCHEMA]
        return schema


def _nested_error(key: str, error: PydanticCustomError | str, data: Any) -> ValidationError:
    return ValidationError.from_exception_data(
        "Pose", [InitErrorDetails(type=error, loc=(key,), input=data)]
    )


def _validate_part(
    model: type[StrictModel], key: str, value: Any, details: list[InitErrorDetails]
) -> Any:
    """``position``/``orientation`` validated with their errors (added to ``details``) at
    their own key, so a quaternion without ``w`` is reported at ``...orientation.w``."""
    try:
        return model.model_validate(value, strict=True)
    except ValidationError as exc:
        for err in exc.errors(include_url=False):
            detail = InitErrorDetails(type=err["type"], loc=(key, *err["loc"]), input=err["input"])
            if "ctx" in err:
                detail["ctx"] = err["ctx"]
            details.append(detail)
        return None


def _number_object(required: list[str], optional: list[str]) -> dict[str, Any]:
    return {
        "type": "object",
        "properties": {k: {"type": "number"} for k in required + optional},
        "required": required,
        "additionalProperties": False,
    }


ROS_POSE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "title": "ROS-style pose",
    "description": "geometry_msgs/Pose: position (z ignored) and a unit quaternion about +z",
    "properties": {
        "position": _number_object(["x", "y"], ["z"]),
        "orientation": _number_object(["z", "w"], ["x", "y"]),
    },
    "required": ["position", "orientation"],
    "additionalProperties": False,
}


#: A goal: a pose, or the label of a room (entered at its anchor or a free point inside).
Goal = Union[Pose, str]  # noqa: UP007


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
