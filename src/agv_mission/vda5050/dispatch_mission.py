"""A mission file as ``vda5050 dispatch`` and ``vda5050 vehicles`` read it: the mission
through the loader, and its tasks' ``actions:`` (pick / drop at a task's nodes) beside it.

``actions:`` is a field only the master knows (``run`` rejects it), so it is taken out of
each task (``tasks.N``, ``robots.K.tasks.N``) of the document as read, and the rest goes
to the loader's models as it is (with the file's lines); the master validates it as
:class:`NodeAction`. A file without it goes to the loader as it is; either way every
problem names the file's own lines and fields.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.loader import load_mission, load_mission_document
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.load.yaml_lines import DocumentError, line_of, load_with_lines


class NodeAction(BaseModel):
    """A load handling action at one of a task's nodes (a dispatched task's ``actions:``),
    sent as a HARD node action of the order (6.8.2 ``pick`` / ``drop``)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    type: Literal["pick", "drop"]
    at: str | None = Field(
        None,
        description="the node: go_to `goal`, patrol `wpN` (each loop), visit_rooms a room "
        "label; default the task's last node",
    )
    duration: float | None = Field(
        None, gt=0, le=3600, description="s the vehicle takes (its own default if not given)"
    )
    load_id: str | None = Field(None, min_length=1, max_length=128)
    load_type: str | None = Field(None, min_length=1, max_length=128)

    def doc(self, action_id: str) -> dict[str, Any]:
        params = {"duration": self.duration, "loadId": self.load_id, "loadType": self.load_type}
        out: dict[str, Any] = {
            "actionId": action_id,
            "actionType": self.type,
            "blockingType": "HARD",
        }
        given = [{"key": k, "value": v} for k, v in params.items() if v is not None]
        if given:
            out["actionParameters"] = given
        return out


@dataclass
class DispatchMission:
    """A loaded mission, its tasks' node actions by where the task is written
    (``tasks.2``, ``robots.0.tasks.1``) and the file's line of each field."""

    loaded: LoadedMission
    actions: dict[str, list[NodeAction]] = field(default_factory=dict)
    lines: dict[Any, int] = field(default_factory=dict)


def field_steps(where: str) -> tuple[Any, ...]:
    """``robots.0.tasks.1`` as a field path: ``("robots", 0, "tasks", 1)``."""
    return tuple(int(p) if p.isdigit() else p for p in where.split(".") if p)


def load_dispatch_mission(
    path: Path,
    overrides: list[str] | None = None,
    seed: int | None = None,
    *,
    tasks_required: bool = True,
    check_actions: bool = True,
) -> DispatchMission:
    """Mission file ``path`` loaded, its ``actions:`` validated (with ``check_actions``;
    the vehicles ignore them). Raises :class:`MissionError` (exit code 2)."""
    try:
        data, lines = load_with_lines(path.read_text(encoding="utf-8"))
    except DocumentError:  # well-formed YAML the loader refuses: it says why, below
        data, lines = None, {}
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MissionError(
            [Problem(str(path), None, "", f"cannot read the mission: {exc}")]
        ) from None
    raw = _take_actions(data) if isinstance(data, dict) else {}
    actions = {w: _node_actions(path, lines, w, r) for w, r in raw.items()} if check_actions else {}
    if not raw:  # the file as written: the loader reads it itself
        loaded = load_mission(path, overrides, seed, tasks_required=tasks_required)
    else:  # the document without its actions, at the file's own lines
        assert isinstance(data, dict)
        loaded = load_mission_document(
            path, data, dict(lines), overrides, seed, tasks_required=tasks_required
        )
    return DispatchMission(loaded, actions, lines)


def _take_actions(doc: dict[str, Any]) -> dict[str, Any]:
    """Every task's ``actions:`` taken out of ``doc`` (in place), by where the task is."""
    lists: list[tuple[str, Any]] = [("tasks", doc.get("tasks"))]
    robots = doc.get("robots")
    for k, robot in enumerate(robots if isinstance(robots, list) else []):
        if isinstance(robot, dict):
            lists.append((f"robots.{k}.tasks", robot.get("tasks")))
    found: dict[str, Any] = {}
    for prefix, tasks in lists:
        for i, task in enumerate(tasks if isinstance(tasks, list) else []):
            if isinstance(task, dict) and "actions" in task:
                found[f"{prefix}.{i}"] = task.pop("actions")
    return found


def _node_actions(path: Path, lines: dict[Any, int], where: str, raw: Any) -> list[NodeAction]:
    """The task at ``where``'s ``actions:``, validated."""
    steps = (*field_steps(where), "actions")
    if raw is None:
        return []
    if not isinstance(raw, list):
        raise MissionError(
            [
                Problem(
                    str(path),
                    line_of(steps, lines),
                    ".".join(map(str, steps)),
                    "a list of {type: pick|drop, at: NODE, duration, load_id, load_type}",
                )
            ]
        )
    out = []
    for j, item in enumerate(raw):
        try:
            out.append(NodeAction.model_validate(item))
        except ValidationError as exc:
            err = exc.errors()[0]
            at = (*steps, j, *tuple(err["loc"]))
            raise MissionError(
                [Problem(str(path), line_of(at, lines), ".".join(map(str, at)), err["msg"])]
            ) from None
    return out
