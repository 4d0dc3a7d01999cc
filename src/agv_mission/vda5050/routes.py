"""A mission's tasks as the routes of VDA 5050 orders: what the master sends, before it sends.

Every task kind an order can carry goes whole: ``go_to`` one node; ``patrol`` its waypoints
loop after loop (``loops: 2`` visits each twice); ``visit_rooms`` its rooms' goals;
``dock`` the dock's staging pose, then the dock with ``startCharging`` on it; ``undock``
``stopCharging`` where the vehicle stands, then the staging pose; ``charge`` a
``startCharging`` where it stands, done when the battery reaches ``until``. A fleet
robot's own ``tasks:`` go to that robot first (``fleet.md``). Angles go out wrapped
into the schemas' bounds (:func:`~agv_mission.vda5050.protocol.schema_angle`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

from agv_mission.fleet.travel import GridTravelTime
from agv_mission.geometry import Pose2D
from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.load.yaml_lines import line_of
from agv_mission.registry import registry
from agv_mission.vda5050.dispatch_mission import NodeAction, field_steps, load_dispatch_mission
from agv_mission.vda5050.protocol import schema_angle

#: the task kinds an order carries
ORDER_TASKS = ("go_to", "patrol", "visit_rooms", "dock", "undock", "charge")


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

    @property
    def number(self) -> int:
        """The task's number in ``tasks:``, from 1, as every report and event counts it
        (``index`` stays 0-based: it names the field ``tasks.N``)."""
        return self.index + 1

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
    room_goals: dict[str, Pose2D],
    actions: list[NodeAction] | None = None,
    lines: dict[Any, int] | None = None,
    where: str | None = None,
    last_dock: str | None = None,
) -> TaskRoute:
    """``task`` (the mission's model of it) as the nodes of an order; ``room_goals`` where
    the robot that does it enters each room."""
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
            goal = room_goals[label]
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
            path = (*field_steps(where), "actions", j, "at")
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


@dataclass(frozen=True)
class _PlannedTask:
    """One task of the mission as the plan takes it: the model, the vehicle it goes to
    (None: dispatched), where it is written and the room goals of the robot doing it."""

    task: Any
    robot: str | None
    where: str
    room_goals: dict[str, Pose2D]


def _no_tree(loaded: LoadedMission, lines: dict[Any, int]) -> None:
    """A behaviour tree runs on the robot: the master refuses one (the mission's or a
    fleet robot's)."""
    mission = loaded.mission
    trees = [("tree",)] if getattr(mission, "tree", None) is not None else []
    trees += [("robots", k, "tree") for k, r in enumerate(mission.robots) if r.tree is not None]
    if trees:
        raise MissionError(
            [
                Problem(
                    str(loaded.source),
                    line_of(trees[0], lines),
                    ".".join(map(str, trees[0])),
                    "a behaviour tree runs on the robot, not as VDA 5050 orders: give the "
                    f"master a `tasks:` list ({', '.join(ORDER_TASKS)})",
                )
            ]
        )


def _planned_tasks(loaded: LoadedMission, robots: list[str]) -> list[_PlannedTask]:
    """Every task of the loaded mission in plan order: a fleet's robots' own tasks first
    (each to its robot), then the fleet's (``robot:`` or dispatched); a one-robot
    mission's tasks to its one vehicle, or dispatched among ``robots``."""
    mission = loaded.mission
    if not mission.robots:
        sole = robots[0] if len(robots) == 1 else None
        return [
            _PlannedTask(task, sole, f"tasks.{i}", loaded.room_goals)
            for i, task in enumerate(mission.tasks or [])
        ]
    planned = [
        _PlannedTask(task, robot.name, f"robots.{k}.tasks.{j}", loaded.robots[k].room_goals)
        for k, robot in enumerate(mission.robots)
        for j, task in enumerate(robot.tasks or [])
    ]
    planned += [
        _PlannedTask(task, loaded.fleet_tasks[j].robot, f"tasks.{j}", loaded.room_goals)
        for j, task in enumerate(mission.tasks or [])
    ]
    if not planned:
        raise MissionError(
            [
                Problem(
                    str(loaded.source),
                    None,
                    "tasks",
                    "the master needs tasks: the fleet's `tasks:` or a robot's own",
                )
            ]
        )
    return planned


def load_plan(
    path: Path,
    overrides: list[str] | None = None,
    seed: int | None = None,
    robots: list[str] | None = None,
) -> MasterPlan:
    """The plan of mission file ``path``, built from the loaded mission's models: a
    one-robot mission drives vehicle ``agv1`` (or ``robots``); a ``robots:`` list names
    the vehicles, each robot's own ``tasks:`` go to it first, and fleet tasks may carry
    ``robot:``."""
    dispatch = load_dispatch_mission(path, overrides, seed)
    loaded, lines = dispatch.loaded, dispatch.lines
    _no_tree(loaded, lines)
    mission = loaded.mission
    names = [r.name for r in mission.robots] or robots or ["agv1"]
    routes: list[TaskRoute] = []
    last_dock: dict[str | None, str] = {}
    for i, p in enumerate(_planned_tasks(loaded, names)):
        route = _route(
            p.task,
            i,
            loaded,
            p.room_goals,
            dispatch.actions.get(p.where),
            lines,
            p.where,
            last_dock.get(p.robot) or last_dock.get(None),
        )
        if p.task.type == "dock":
            last_dock[p.robot] = p.task.dock
        route.robot = p.robot
        routes.append(route)
    nav = mission.stack.navigation
    return MasterPlan(
        loaded.name,
        names,
        routes,
        loaded.world.name,
        nav.xy_goal_tolerance,
        nav.yaw_goal_tolerance,
        mission.limits.time,
        Path(mission.output),
        loaded.resolved(),
        dispatcher=registry.create("dispatcher", mission.fleet.dispatcher),
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
