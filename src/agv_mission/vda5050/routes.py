"""A mission's tasks as the routes of VDA 5050 orders: what the master sends, before it sends.

Every task kind an order can carry goes whole: ``go_to`` one node; ``patrol`` its waypoints
loop after loop (``loops: 2`` visits each twice); ``visit_rooms`` its rooms' goals;
``dock`` the dock's staging pose, then the dock with ``startCharging`` on it; ``undock``
``stopCharging`` where the vehicle stands, then the staging pose; ``charge`` a
``startCharging`` where it stands, done when the battery reaches ``until``. A fleet
robot's own ``tasks:`` go to that robot first (``fleet.md``). Angles go out wrapped
into the schemas' bounds (:func:`~agv_mission.vda5050.messages.schema_angle`).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from agv_mission.fleet.travel import GridTravelTime
from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.loader import LoadedMission, load_mission
from agv_mission.missions.yaml_lines import line_of, load_with_lines
from agv_mission.registry import registry
from agv_mission.vda5050.messages import schema_angle

#: the task kinds an order carries
ORDER_TASKS = ("go_to", "patrol", "visit_rooms", "dock", "undock", "charge")


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


@dataclass(frozen=True)
class ChargeAction:
    """``startCharging`` / ``stopCharging`` on a node (6.8.1: node scope), HARD: the
    vehicle stands while it connects to or leaves the charger."""

    type: Literal["startCharging", "stopCharging"]

    def doc(self, action_id: str) -> dict[str, Any]:
        return {"actionId": action_id, "actionType": self.type, "blockingType": "HARD"}


OrderAction = NodeAction | ChargeAction


@dataclass(frozen=True)
class RouteNode:
    node_id: str
    x: float
    y: float
    theta: float | None
    actions: tuple[OrderAction, ...] = ()


@dataclass
class TaskRoute:
    """One task as the nodes an order visits."""

    index: int
    type: str
    nodes: list[RouteNode]
    robot: str | None = None  # the vehicle the mission assigns, if any
    retries: int = 0  # extra attempts left (on_failure: retry)
    on_failure: str = "abort"
    status: str = "pending"  # pending | running | succeeded | failed | skipped
    reason: str | None = None
    assigned: str | None = None
    actions: dict[str, dict[str, Any]] = field(default_factory=dict)  # by actionId, as done
    #: actions on the order's first node (where the vehicle stands when it gets the order)
    start_actions: tuple[OrderAction, ...] = ()
    #: ``charge``: the battery level (0..1) the task waits for
    charge_until: float | None = None
    #: where the task is written in the mission file (``tasks.2``, ``robots.0.tasks.1``)
    where: str = ""

    def charged(self, state: dict[str, Any]) -> bool:
        """A ``charge`` task is done when the vehicle's ``batteryCharge`` reached its level
        (always True for the other tasks)."""
        if self.charge_until is None:
            return True
        try:
            level = float((state.get("batteryState") or {}).get("batteryCharge", 0.0))
        except (TypeError, ValueError):
            return False
        return level >= 100.0 * self.charge_until - 1e-6


@dataclass
class MasterPlan:
    """What ``dispatch`` drives: vehicles by serial number, tasks, the map, tolerances."""

    name: str
    robots: list[str]
    tasks: list[TaskRoute]
    map_id: str
    xy_tolerance: float
    yaw_tolerance: float
    time_limit: float  # wall seconds
    output: Path
    resolved: dict[str, Any] = field(default_factory=dict)
    #: the fleet layer's dispatcher (fleet.md's `fleet.dispatcher`) and its travel times
    #: over the map (the mission's first robot's free space, at its top speed)
    dispatcher: Any = None
    travel: Any = None


def _theta(yaw: float | None) -> float | None:
    return None if yaw is None else schema_angle(yaw)


def _route(
    task: Any,
    index: int,
    loaded: LoadedMission,
    actions: list[NodeAction] | None = None,
    lines: dict[Any, int] | None = None,
    where: str | None = None,
    last_dock: str | None = None,
) -> TaskRoute:
    kind = task.type
    where = where or f"tasks.{index}"
    nodes: list[RouteNode] = []
    start: tuple[OrderAction, ...] = ()
    until = None
    if kind == "go_to":
        nodes = [RouteNode(f"goal{index + 1}", task.pose.x, task.pose.y, _theta(task.pose.yaw))]
    elif kind == "patrol":
        for _ in range(task.loops):
            nodes += [
                RouteNode(f"wp{k + 1}", p.x, p.y, _theta(p.yaw))
                for k, p in enumerate(task.waypoints)
            ]
    elif kind == "visit_rooms":
        for label in task.rooms:
            goal = loaded.room_goals[label]
            nodes.append(RouteNode(label, goal.x, goal.y, None))
    elif kind in ("dock", "undock"):
        name = task.dock if kind == "dock" else (last_dock or "charger")
        dock = loaded.docks.get(name)
        if dock is None:
            raise MissionError(
                [
                    Problem(
                        str(loaded.source),
                        None,
                        f"{where}.dock" if kind == "dock" else where,
                        f"no dock {name!r} (docks: {', '.join(loaded.docks) or 'none'})",
                    )
                ]
            )
        staging, yaw = dock.staging(), _theta(dock.pose.yaw)
        stage = RouteNode(f"{name}_staging", staging.x, staging.y, yaw)
        if kind == "dock":
            at = RouteNode(name, dock.pose.x, dock.pose.y, yaw, (ChargeAction("startCharging"),))
            nodes = [stage, at]
        else:
            nodes, start = [stage], (ChargeAction("stopCharging"),)
    elif kind == "charge":
        start, until = (ChargeAction("startCharging"),), float(task.until)
    else:
        raise MissionError(
            [
                Problem(
                    str(loaded.source),
                    None,
                    f"{where}.type",
                    f"{kind}: not a task a VDA 5050 order can carry ({', '.join(ORDER_TASKS)})",
                )
            ]
        )
    nodes = _with_actions(nodes, actions or [], kind, where, loaded, lines or {})
    policy = getattr(task, "on_failure", "abort")
    retries = getattr(task, "retries", 0) if policy == "retry" else 0
    return TaskRoute(
        index,
        kind,
        nodes,
        retries=retries,
        on_failure=policy,
        start_actions=start,
        charge_until=until,
        where=where,
    )


def _with_actions(
    nodes: list[RouteNode],
    actions: list[NodeAction],
    kind: str,
    where: str,
    loaded: LoadedMission,
    lines: dict[Any, int],
) -> list[RouteNode]:
    """``nodes`` with each action on the nodes it names (``go_to``'s node is ``goal``)."""
    if actions and not nodes:
        raise MissionError(
            [Problem(str(loaded.source), None, f"{where}.actions", f"a {kind} task has no node")]
        )
    ids = ["goal" if kind == "go_to" else n.node_id for n in nodes]
    on: list[list[OrderAction]] = [list(n.actions) for n in nodes]
    for j, act in enumerate(actions):
        at = act.at if act.at is not None else ids[-1]
        hits = [i for i, node_id in enumerate(ids) if node_id == at]
        if not hits:
            names = ", ".join(dict.fromkeys(ids))
            path = (*_steps(where), "actions", j, "at")
            raise MissionError(
                [
                    Problem(
                        str(loaded.source),
                        line_of(path, lines),
                        f"{where}.actions.{j}.at",
                        f"{at!r} is not a node of this {kind} task (its nodes: {names})",
                    )
                ]
            )
        for i in hits:
            on[i].append(act)
    return [replace(n, actions=tuple(a)) for n, a in zip(nodes, on, strict=True)]


def _steps(where: str) -> tuple[Any, ...]:
    return tuple(int(p) if p.isdigit() else p for p in where.split("."))


def _lines(text: str) -> dict[Any, int]:
    try:
        return load_with_lines(text)[1]
    except yaml.YAMLError:
        return {}


def _pop_actions(
    path: Path, lines: dict[Any, int], tasks: list[Any], prefix: tuple[Any, ...] = ("tasks",)
) -> list[list[NodeAction]]:
    """Take each task's ``actions:`` (a dispatch-only field) out of ``tasks``, validated."""
    out: list[list[NodeAction]] = []
    for i, task in enumerate(tasks):
        raw = task.pop("actions", None) if isinstance(task, dict) else None
        if raw is None:
            out.append([])
            continue
        if not isinstance(raw, list):
            where = (*prefix, i, "actions")
            raise MissionError(
                [
                    Problem(
                        str(path),
                        line_of(where, lines),
                        ".".join(map(str, where)),
                        "a list of {type: pick|drop, at: NODE, duration, load_id, load_type}",
                    )
                ]
            )
        acts = []
        for j, item in enumerate(raw):
            try:
                acts.append(NodeAction.model_validate(item))
            except ValidationError as exc:
                err = exc.errors()[0]
                where = (*prefix, i, "actions", j, *tuple(err["loc"]))
                raise MissionError(
                    [
                        Problem(
                            str(path),
                            line_of(where, lines),
                            ".".join(str(p) for p in where),
                            err["msg"],
                        )
                    ]
                ) from None
        out.append(acts)
    return out


def _no_tree(path: Path, lines: dict[Any, int], doc: dict[str, Any], where: tuple) -> None:
    if "tree" in doc:
        raise MissionError(
            [
                Problem(
                    str(path),
                    line_of((*where, "tree"), lines),
                    ".".join(map(str, (*where, "tree"))),
                    "a behaviour tree runs on the robot, not as VDA 5050 orders: give the "
                    f"master a `tasks:` list ({', '.join(ORDER_TASKS)})",
                )
            ]
        )


def _load_as_written(
    path: Path,
    overrides: list[str] | None,
    seed: int | None,
    one: dict[str, Any],
    wheres: list[str],
    lines: dict[Any, int],
) -> LoadedMission:
    """Load the one-robot mission made of a fleet's tasks; its problems name the fields
    and lines of the file as written (``robots.0.tasks.1.pose``, not ``tasks.1.pose``)."""
    try:
        return load_mission(path, overrides, seed, text=yaml.safe_dump(one, sort_keys=False))
    except MissionError as exc:
        problems = []
        for p in exc.problems:
            head, _, rest = p.field.partition(".")
            index, _, tail = rest.partition(".")
            if head == "tasks" and index.isdigit() and int(index) < len(wheres):
                field_ = wheres[int(index)] + (f".{tail}" if tail else "")
                line = line_of(_steps(field_), lines) or p.line
                problems.append(replace(p, field=field_, line=line))
            else:
                problems.append(p)
        raise MissionError(problems) from None


def load_plan(
    path: Path,
    overrides: list[str] | None = None,
    seed: int | None = None,
    robots: list[str] | None = None,
) -> MasterPlan:
    """The plan of mission file ``path``: a one-robot mission drives vehicle ``agv1`` (or
    ``robots``); a ``robots:`` list names the vehicles, each robot's own ``tasks:`` go
    to it first, and fleet tasks may carry ``robot:``."""
    try:
        text = path.read_text(encoding="utf-8")
        doc = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MissionError(
            [Problem(str(path), None, "", f"cannot read the mission: {exc}")]
        ) from None
    lines = _lines(text)
    if not isinstance(doc, dict):
        raise MissionError([Problem(str(path), None, "", "a mission is a YAML mapping")])
    _no_tree(path, lines, doc, ())
    assigned: list[str | None] = []
    wheres: list[str] = []
    if isinstance(doc.get("robots"), list) and doc["robots"]:
        names = [r.get("name") for r in doc["robots"] if isinstance(r, dict)]
        if not all(isinstance(n, str) for n in names) or len(set(names)) != len(names):
            raise MissionError(
                [Problem(str(path), None, "robots", "each robot needs a unique name")]
            )
        one = {k: copy.deepcopy(v) for k, v in doc.items() if k not in ("robots", "fleet", "tasks")}
        first = doc["robots"][0]
        for key in ("robot", "start"):
            if key in first:
                one[key] = first[key]
        tasks: list[Any] = []
        actions: list[list[NodeAction]] = []
        for k, robot in enumerate(doc["robots"]):  # a robot's own tasks run first
            _no_tree(path, lines, robot, ("robots", k))
            own = [dict(t) if isinstance(t, dict) else t for t in robot.get("tasks") or []]
            actions += _pop_actions(path, lines, own, ("robots", k, "tasks"))
            tasks += own
            assigned += [robot["name"]] * len(own)
            wheres += [f"robots.{k}.tasks.{j}" for j in range(len(own))]
        fleet = [dict(t) if isinstance(t, dict) else t for t in doc.get("tasks") or []]
        for j, task in enumerate(fleet):
            assigned.append(task.pop("robot", None) if isinstance(task, dict) else None)
            wheres.append(f"tasks.{j}")
        actions += _pop_actions(path, lines, fleet)
        one["tasks"] = tasks + fleet
        loaded = _load_as_written(path, overrides, seed, one, wheres, lines)
        robot_names = list(names)
    else:
        tasks = doc.get("tasks")
        if isinstance(tasks, list) and any(isinstance(t, dict) and "actions" in t for t in tasks):
            tasks = [dict(t) if isinstance(t, dict) else t for t in tasks]
            actions = _pop_actions(path, lines, tasks)
            one = {**doc, "tasks": tasks}
            loaded = load_mission(path, overrides, seed, text=yaml.safe_dump(one, sort_keys=False))
        else:
            loaded = load_mission(path, overrides, seed)
            actions = []
        robot_names = robots or ["agv1"]
        n = len(loaded.mission.tasks or [])
        assigned = [robot_names[0] if len(robot_names) == 1 else None] * n
        wheres = [f"tasks.{i}" for i in range(n)]
    routes: list[TaskRoute] = []
    last_dock: dict[str | None, str] = {}
    for i, task in enumerate(loaded.mission.tasks or []):
        robot = assigned[i]
        route = _route(
            task,
            i,
            loaded,
            actions[i] if i < len(actions) else None,
            lines,
            wheres[i],
            last_dock.get(robot) or last_dock.get(None),
        )
        if task.type == "dock":
            last_dock[robot] = task.dock
        routes.append(route)
    for route, robot in zip(routes, assigned, strict=True):
        if robot is not None and robot not in robot_names:
            raise MissionError(
                [
                    Problem(
                        str(path),
                        None,
                        f"{route.where}.robot",
                        f"{robot!r} is not one of robots {robot_names}",
                    )
                ]
            )
        route.robot = robot
    nav = loaded.mission.stack.navigation
    return MasterPlan(
        loaded.name,
        robot_names,
        routes,
        loaded.world.name,
        nav.xy_goal_tolerance,
        nav.yaw_goal_tolerance,
        loaded.mission.limits.time,
        Path(loaded.mission.output),
        loaded.resolved(),
        dispatcher=registry.create("dispatcher", loaded.mission.fleet.dispatcher),
        travel=GridTravelTime(loaded.costmap, loaded.robot.max_linear_velocity),
    )


def place(node: RouteNode) -> str:
    """Where a node is, to the decimetre: two orders' nodes at one place are one resource
    whatever their ids (every patrol calls its waypoints wp1, wp2, ...)."""
    return f"{round(node.x, 1):g},{round(node.y, 1):g}"


class NodeReservations:
    """Traffic control as the master can do it without a fleet world: a node's place is
    granted to one vehicle at a time; a vehicle frees a place when it has left it."""

    def __init__(self) -> None:
        self.holder: dict[str, str] = {}

    def grant(self, robot: str, node: RouteNode) -> bool:
        owner = self.holder.setdefault(place(node), robot)
        return owner == robot

    def keep_only(self, robot: str, places: set[str]) -> None:
        for key, owner in list(self.holder.items()):
            if owner == robot and key not in places:
                del self.holder[key]
