"""The API's bodies and answers as pydantic models: the OpenAPI document (``/openapi.json``)
is generated from them, so a client can be generated from it in turn.

Answers that carry more than the contract fixes (a run's ``result`` is the whole
``result.json``) allow extra keys: the contract says "at least", and a client keeps them.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import Query
from pydantic import BaseModel, ConfigDict, Field
from pydantic.json_schema import SkipJsonSchema

Status = Literal[
    "queued", "running", "paused", "succeeded", "failed", "aborted", "error", "interrupted"
]


class Open(BaseModel):
    """An answer that may carry more keys than it documents."""

    model_config = ConfigDict(extra="allow")


class Health(BaseModel):
    """Liveness and load."""

    status: Literal["ok"] = Field(description="always ok while the service answers")
    version: str = Field(description="the installed agv-mission version")
    queued: int = Field(ge=0, description="runs waiting for a worker")
    running: int = Field(ge=0, description="runs on a worker now")
    workers: int = Field(ge=1, description="missions run at once")
    backend: str = Field(description="local (processes) or ray")


class RobotProgress(BaseModel):
    """Where one robot of a run is: its current task and a one-line detail."""

    task_index: int | None = Field(None, description="index of its current task in its tree")
    task_type: str | None = Field(None, description="type of its current task")
    detail: str = Field("", description="one line about what the robot is doing")


class Progress(Open):
    """Where a run is: simulated time, the current task, a one-line detail (the first
    robot's; every robot's under ``robots``)."""

    sim_time: float = Field(description="simulated seconds so far")
    task_index: int | None = Field(None, description="index of the current task in `tasks`")
    task_type: str | None = Field(None, description="type of the current task")
    detail: str = Field("", description="one line about what the robot is doing")
    robots: dict[str, RobotProgress] | None = Field(
        None, description="every robot's task and detail by name (a fleet's namespaces)"
    )


class Run(Open):
    """One mission execution. Times are ISO 8601 UTC; ``result`` (the content of
    ``result.json``) once the run is final."""

    id: str
    name: str
    status: Status
    reason: str | None = Field(None, description="why it ended as it did (null on success)")
    created: str
    started: str | None = None
    ended: str | None = None
    progress: Progress
    seed: int | None = Field(None, description="the seed the submission overrode, if any")
    set: list[str] = Field(default_factory=list, description="the submission's --set overrides")
    pace: float | None = Field(
        None,
        description="simulated seconds per wall second (null: as fast as it goes); "
        "POST /api/runs/{id}/pace changes it while the run runs",
    )
    result: dict[str, Any] | None = Field(
        None, description="the content of result.json, once final"
    )


class RunList(BaseModel):
    """Runs, newest first."""

    runs: list[Run]


class Problem(BaseModel):
    """One problem of invalid input, as the command line prints it."""

    line: int | None = Field(description="line in the mission text (null: not from a line)")
    field: str = Field(description="the field, list indices in brackets: tasks[0].pose.x")
    message: str


class Problems(BaseModel):
    """Invalid input (422): every problem found."""

    errors: list[Problem]
    detail: str | None = Field(None, description="the first problem's message")


class Detail(BaseModel):
    """Any other refusal: what was wrong."""

    detail: str


class Submit(BaseModel):
    """A mission to run: its YAML text with ``--set`` overrides and a seed."""

    model_config = ConfigDict(extra="forbid")

    mission: str = Field(description="the mission file's YAML text")
    set: list[str] = Field(
        default_factory=list,
        description="KEY=VALUE overrides, as --set on the command line",
        examples=[["stack.local_planner.type=pure_pursuit"]],
    )
    seed: int | None = Field(None, ge=0, description="overrides the mission's seed")
    pace: float | None = Field(
        None,
        gt=0,
        description="simulated seconds per wall second, so that a person can watch and "
        "steer (1.0: real time); absent: as fast as the run goes",
        examples=[1.0],
    )


class Pace(BaseModel):
    """A new pace for a run: simulated seconds per wall second (null: as fast as it goes)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    pace: float | None = Field(
        gt=0,
        description="simulated seconds per wall second; null: as fast as it goes",
        examples=[4.0],
    )


class PaceSet(BaseModel):
    id: str
    pace: float | None


def _no_default(schema: dict[str, Any]) -> None:
    """A multipart field left out has no value at all (not null)."""
    schema.pop("default", None)


class SubmitWithFiles(BaseModel):
    """A mission with the files it names (multipart/form-data): the world's map YAML and
    image, rooms file, robot file, recorder file. Each file part's filename is its path
    relative to the mission file, as the mission names it (``maps/house.yaml``); they land
    in the run's own directory (``inputs/``)."""

    mission: str = Field(description="the mission's YAML text (a text field or a file part)")
    mission_path: str | SkipJsonSchema[None] = Field(
        None,
        description="where the mission file sits among the files (default: the mission "
        "part's filename, else mission.yaml)",
        json_schema_extra=_no_default,
    )
    set: list[str] = Field(default_factory=list, description="KEY=VALUE overrides")
    seed: Annotated[int, Field(ge=0)] | SkipJsonSchema[None] = Field(
        None, description="overrides the mission's seed", json_schema_extra=_no_default
    )
    pace: Annotated[float, Field(gt=0)] | SkipJsonSchema[None] = Field(
        None,
        description="simulated seconds per wall second (absent: as fast as it goes)",
        json_schema_extra=_no_default,
    )
    files: list[bytes] = Field(
        default_factory=list,
        description="the files the mission names, filename = path relative to the mission",
        json_schema_extra={"items": {"type": "string", "format": "binary"}},
    )


class Validated(BaseModel):
    """A valid mission, resolved (defaults filled in, overrides applied)."""

    ok: Literal[True]
    mission: dict[str, Any]


class Command(BaseModel):
    """A command the run's worker was sent."""

    id: str
    status: str = Field(description="what the run is now doing: cancelling, paused, running")


class Goal(BaseModel):
    """A navigation goal for a run whose current task is teleop ("2D Nav Goal")."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    x: float = Field(description="m, map frame")
    y: float = Field(description="m, map frame")
    yaw: float = Field(0.0, description="rad")


class GoalSent(BaseModel):
    id: str
    goal: Goal
    robot: str = Field(description="the robot driving there")


class FileList(BaseModel):
    """Every file of the run directory, those in folders too (``bag/metadata.yaml``,
    ``bag/bag_0.mcap``) as paths relative to it; fetch each one by that path."""

    files: list[str]


class Pose(BaseModel):
    x: float
    y: float
    yaw: float


class RoomRecord(BaseModel):
    """The seed's ``rosservice call room_service "kitchen"`` answer."""

    confirmation: str = Field(examples=["Entry saved in file"])
    label: str
    pose: Pose
    robot: str | None = Field(None, description="the robot whose pose was recorded")


RobotName = Annotated[
    str | None,
    Query(
        description="the robot (its name in the mission's `robots:`); may be omitted when "
        "the run has one robot",
        max_length=64,
    ),
]


class StreamNode(BaseModel):
    """One behaviour of a robot's tree, as the live stream's ``tree`` messages carry it."""

    name: str
    status: Literal["SUCCESS", "FAILURE", "RUNNING", "INVALID"]
    depth: int = Field(ge=0)


class StreamRobot(BaseModel):
    """One robot of a run, as the live stream's ``robots`` message lists it at the start."""

    name: str = Field(description="its name: the ROS namespace in a fleet mission")
    type: str = Field(description="the robot model (burger, waffle, a robot file's name)")
    colour: str = Field(description="#rrggbb: its colour on the dashboard and in run.png")
    radius: float = Field(gt=0, description="footprint radius, m (round it, for a polygon)")
    footprint: list[tuple[float, float]] | None = Field(
        None, description="the footprint polygon, robot frame (m); none: a round robot"
    )
    start: Pose
    tree: list[StreamNode] = Field(description="its behaviour tree, pre-order")


class StreamRobots(BaseModel):
    """The live stream's ``robots`` message: every robot of the run (sent at the start,
    before any robot's own). Every per-robot message that follows (state, scan, plan, goal, tree,
    particles, horizon, event) names its robot in ``robot``."""

    type: Literal["robots"] = "robots"
    fleet: bool = Field(description="a fleet mission (`robots:`); false: one robot")
    robots: list[StreamRobot]


class Template(BaseModel):
    name: str
    yaml: str


class Templates(BaseModel):
    """The demo missions, for the submit page."""

    templates: list[Template]


def answers(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """The documented refusals of a route: 422 with the problems, the rest with a detail."""
    documented: dict[int | str, dict[str, Any]] = {}
    for status in sorted({*statuses, 422}):  # a malformed path or query answers 422 too
        model = Problems if status == 422 else Detail
        documented[status] = {"model": model, "description": REFUSALS.get(status, "refused")}
    return documented


REFUSALS = {
    401: "missing or wrong bearer token",
    404: "no such run or file",
    409: "the run is not in a state for this",
    413: "the body is too large",
    415: "an unsupported media type",
    422: "invalid input",
    429: "the queue is full",
    500: "the run could not do it",
    503: "the run did not answer in time",
}


def request_body(
    model: type[BaseModel], *, yaml: bool = False, multipart: bool = False
) -> dict[str, Any]:
    """``openapi_extra`` for a route that reads its body itself (bounded, several media
    types): the body's schema by reference (:func:`body_schemas` puts it in components),
    as JSON or as multipart, and the YAML text alone when ``yaml``."""
    schema = {"$ref": f"#/components/schemas/{model.__name__}"}
    content: dict[str, Any] = {}
    if multipart:
        content["multipart/form-data"] = {
            "schema": schema,
            "encoding": {"files": {"contentType": "application/octet-stream"}},
        }
    else:
        content["application/json"] = {"schema": schema}
    if yaml:
        content["application/yaml"] = {
            "schema": {"type": "string", "description": "the mission's YAML text alone"}
        }
    return {"requestBody": {"required": True, "content": content}}


BODY_MODELS: tuple[type[BaseModel], ...] = (Submit, SubmitWithFiles, Goal, Pace)
STREAM_MODELS: tuple[type[BaseModel], ...] = (StreamRobots,)  # live-stream messages


def body_schemas() -> dict[str, Any]:
    """The component schemas of the bodies routes read themselves, and of the live
    stream's typed messages (a WebSocket has no route schema of its own)."""
    schemas: dict[str, Any] = {}
    for model in (*BODY_MODELS, *STREAM_MODELS):
        schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
        schemas.update(schema.pop("$defs", {}))
        schemas[model.__name__] = schema
    return schemas
