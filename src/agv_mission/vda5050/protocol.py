"""The VDA 5050 2.1.0 protocol: its messages as pydantic models, field for field as the
standard's JSON schemas, its topics, timestamps and angle bounds.

Incoming messages (``order``, ``instantActions``) are parsed strictly: a field of the wrong
type or a missing required one is the standard's ``validationError`` (6.6.4.1). Outgoing
ones are built from these models and dumped without ``None`` fields, so every optional field
the vehicle does not know is left out rather than sent as ``null`` (the schemas forbid it).
Tests validate what these models produce against the schema files themselves.
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

VERSION = "2.1.0"
INTERFACE = "uagv"
MAJOR = "v2"

ActionStatus = Literal["WAITING", "INITIALIZING", "RUNNING", "FINISHED", "FAILED"]
BlockingType = Literal["NONE", "SOFT", "HARD"]
ErrorLevel = Literal["WARNING", "FATAL"]
ConnectionState = Literal["ONLINE", "OFFLINE", "CONNECTIONBROKEN"]


#: the schemas' bound of an angle (``nodePosition.theta``, ``edge.orientation``), rad
ANGLE_BOUND = 3.14159265359
#: the schema's bound of ``allowedDeviationTheta``, rad
DEVIATION_THETA_BOUND = 3.141592654


def schema_angle(angle: float) -> float:
    """``angle`` wrapped into [-pi, pi] and kept within the schemas' bound (a mission's
    ``yaw: 3.1416``, written to four decimals, is above pi: it goes out as -3.14159)."""
    wrapped = (angle + math.pi) % (2.0 * math.pi) - math.pi
    return max(-ANGLE_BOUND, min(ANGLE_BOUND, wrapped))


def deviation_angle(angle: float) -> float:
    """A tolerance angle within ``allowedDeviationTheta``'s bounds [0, pi]."""
    return max(0.0, min(DEVIATION_THETA_BOUND, angle))


def timestamp(now: datetime | None = None) -> str:
    """ISO 8601 UTC, as the standard's examples: ``2017-04-15T11:40:03.12Z``."""
    now = now or datetime.now(timezone.utc)
    return now.strftime("%Y-%m-%dT%H:%M:%S.") + f"{now.microsecond // 1000:03d}Z"


def parse_timestamp(text: str) -> datetime:
    return datetime.fromisoformat(text.replace("Z", "+00:00"))


class Message(BaseModel):
    """Common to every message: what ``model_dump`` leaves out and how it parses."""

    model_config = ConfigDict(extra="ignore", strict=True)

    def doc(self) -> dict[str, Any]:
        return self.model_dump(mode="json", exclude_none=True, by_alias=True)


class Header(Message):
    headerId: int = Field(ge=0)
    timestamp: str
    version: str
    manufacturer: str
    serialNumber: str


# --------------------------------------------------------------------------- order


class ActionParameter(Message):
    key: str
    value: Any


class Action(Message):
    actionType: str
    actionId: str
    actionDescription: str | None = None
    blockingType: BlockingType
    actionParameters: list[ActionParameter] | None = None

    def param(self, key: str, default: Any = None) -> Any:
        for p in self.actionParameters or []:
            if p.key == key:
                return p.value
        return default


class NodePosition(Message):
    x: float
    y: float
    theta: float | None = Field(None, ge=-ANGLE_BOUND, le=ANGLE_BOUND)
    allowedDeviationXY: float | None = Field(None, ge=0)
    allowedDeviationTheta: float | None = Field(None, ge=0, le=DEVIATION_THETA_BOUND)
    mapId: str
    mapDescription: str | None = None


class Node(Message):
    nodeId: str
    sequenceId: int = Field(ge=0)
    nodeDescription: str | None = None
    released: bool
    nodePosition: NodePosition | None = None
    actions: list[Action]


class Trajectory(Message):
    degree: float
    knotVector: list[float]
    controlPoints: list[dict[str, float]]


class Edge(Message):
    edgeId: str
    sequenceId: int = Field(ge=0)
    edgeDescription: str | None = None
    released: bool
    startNodeId: str
    endNodeId: str
    maxSpeed: float | None = None
    maxHeight: float | None = None
    minHeight: float | None = None
    orientation: float | None = Field(None, ge=-ANGLE_BOUND, le=ANGLE_BOUND)
    orientationType: Literal["GLOBAL", "TANGENTIAL"] | None = None
    direction: str | None = None
    rotationAllowed: bool | None = None
    maxRotationSpeed: float | None = None
    length: float | None = None
    trajectory: Trajectory | None = None
    corridor: dict[str, Any] | None = None
    actions: list[Action]


class Order(Header):
    orderId: str
    orderUpdateId: int = Field(ge=0)
    zoneSetId: str | None = None
    nodes: list[Node] = Field(min_length=1)
    edges: list[Edge]


class InstantActions(Header):
    actions: list[Action]


# --------------------------------------------------------------------------- state


class ErrorReference(Message):
    referenceKey: str
    referenceValue: str


class Error(Message):
    errorType: str
    errorReferences: list[ErrorReference] | None = None
    errorDescription: str | None = None
    errorLevel: ErrorLevel


class NodeState(Message):
    nodeId: str
    sequenceId: int
    nodeDescription: str | None = None
    released: bool
    nodePosition: NodePosition | None = None


class EdgeState(Message):
    edgeId: str
    sequenceId: int
    edgeDescription: str | None = None
    released: bool


class AgvPosition(Message):
    x: float
    y: float
    theta: float
    mapId: str
    positionInitialized: bool
    localizationScore: float | None = None
    deviationRange: float | None = None


class Velocity(Message):
    vx: float | None = None
    vy: float | None = None
    omega: float | None = None


class Load(Message):
    loadId: str | None = None
    loadType: str | None = None
    loadPosition: str | None = None
    weight: float | None = None


class ActionState(Message):
    actionId: str
    actionType: str | None = None
    actionDescription: str | None = None
    actionStatus: ActionStatus
    resultDescription: str | None = None


class BatteryState(Message):
    batteryCharge: float
    batteryVoltage: float | None = None
    batteryHealth: float | None = None
    charging: bool
    reach: float | None = None


class SafetyState(Message):
    eStop: Literal["AUTOACK", "MANUAL", "REMOTE", "NONE"]
    fieldViolation: bool


class Information(Message):
    infoType: str
    infoReferences: list[ErrorReference] | None = None
    infoDescription: str | None = None
    infoLevel: Literal["INFO", "DEBUG"]


class State(Header):
    orderId: str
    orderUpdateId: int
    lastNodeId: str
    lastNodeSequenceId: int
    nodeStates: list[NodeState]
    edgeStates: list[EdgeState]
    agvPosition: AgvPosition | None = None
    velocity: Velocity | None = None
    loads: list[Load] | None = None
    driving: bool
    paused: bool | None = None
    newBaseRequest: bool | None = None
    distanceSinceLastNode: float | None = None
    actionStates: list[ActionState]
    batteryState: BatteryState
    operatingMode: Literal["AUTOMATIC", "SEMIAUTOMATIC", "MANUAL", "SERVICE", "TEACHIN"]
    errors: list[Error]
    information: list[Information] | None = None
    safetyState: SafetyState


class Visualization(Header):
    agvPosition: AgvPosition | None = None
    velocity: Velocity | None = None


class Connection(Header):
    connectionState: ConnectionState


class Factsheet(Header):
    typeSpecification: dict[str, Any]
    physicalParameters: dict[str, Any]
    protocolLimits: dict[str, Any]
    protocolFeatures: dict[str, Any]
    agvGeometry: dict[str, Any]
    loadSpecification: dict[str, Any]
    vehicleConfig: dict[str, Any] | None = None


TOPIC_MODELS: dict[str, type[Header]] = {
    "order": Order,
    "instantActions": InstantActions,
    "state": State,
    "visualization": Visualization,
    "connection": Connection,
    "factsheet": Factsheet,
}


def topic(manufacturer: str, serial: str, name: str) -> str:
    """``uagv/v2/{manufacturer}/{serialNumber}/{topic}`` (6.3)."""
    return f"{INTERFACE}/{MAJOR}/{manufacturer}/{serial}/{name}"


def split_topic(name: str) -> tuple[str, str, str] | None:
    """(manufacturer, serialNumber, topic) of a VDA 5050 topic, or None."""
    parts = name.split("/")
    if len(parts) != 5 or parts[0] != INTERFACE or parts[1] != MAJOR:
        return None
    return parts[2], parts[3], parts[4]
