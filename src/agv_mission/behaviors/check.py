"""``check_node``: does a node type keep the ``behavior`` slot's contract? (what
``check_plugin(cls, "behavior")`` runs)

Statically: ``Config`` is a :class:`~agv_mission.behaviors.ports.NodePorts` whose ``type``
is one name and whose ``kind`` is known, the class is a py_trees behaviour, and its
constructor takes ``(name, handle | child | children)`` and every port. Then one instance
is built with the ports given (or the defaults, or ``Config.example``) and ticked for up
to ``TICKS`` control steps in a 4 m x 4 m walled room, the robot moving as commanded; each
tick must give a status, a condition must end in its first tick, and a node halted while
running must leave the navigator idle (a halted action releases what it holds).
"""

from __future__ import annotations

import inspect
import math
import typing

import numpy as np
import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.ports.node import NodePorts
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.maps.rooms import Room
from agv_mission.navigation.config import NavigationConfig
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import Navigator, NavStatus
from agv_mission.navigation.state import RobotState
from agv_mission.planners.base import VelocityLimits
from agv_mission.registry import registry
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.sensor_msgs import LaserScan

ROOM = 4.0  # m, the side of the test room
RESOLUTION = 0.05
PERIOD = 0.05  # s, one control step
TICKS = 200
KINDS = ("action", "condition", "control", "decorator")


class NodeCheckError(AssertionError):
    """The node type breaks the slot's contract; the message says how."""


def static_problems(cls: type) -> list[str]:
    """What is wrong with ``cls`` as a node type, without building it."""
    problems: list[str] = []
    config = getattr(cls, "Config", None)
    if not (isinstance(config, type) and issubclass(config, NodePorts)):
        return ["Config must be a subclass of agv_mission.behaviors.ports.NodePorts"]
    field = config.model_fields.get("type")
    args = typing.get_args(field.annotation) if field is not None else ()
    if len(args) != 1 or not isinstance(args[0], str):
        problems.append("Config needs a 'type' field: a Literal of the node type's name")
    if config.kind not in KINDS:
        problems.append(f"Config.kind must be one of {', '.join(KINDS)}, not {config.kind!r}")
    if not issubclass(cls, py_trees.behaviour.Behaviour):
        problems.append("the node must be a py_trees.behaviour.Behaviour")
    params = inspect.signature(cls.__init__).parameters
    names = list(params)[1:]
    second = {"action": "handle", "condition": "handle", "decorator": "child"}.get(
        config.kind, "children"
    )
    if names[:2] != ["name", second]:
        problems.append(f"__init__ must take (name, {second}, **ports), takes {names}")
    varkw = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
    for port in config.model_fields:
        if port != "type" and port not in params and not varkw:
            problems.append(f"__init__ does not take the port {port!r}")
    return problems


def _room() -> tuple[Costmap, dict[str, Room]]:
    n = int(round(ROOM / RESOLUTION))
    data = np.full((n, n), FREE, dtype=np.int8)
    data[[0, -1], :] = OCCUPIED
    data[:, [0, -1]] = OCCUPIED
    grid = OccupancyGrid(data, RESOLUTION, Pose2D(0.0, 0.0, 0.0))
    room = Room("room", ((0.1, 0.1), (3.9, 0.1), (3.9, 3.9), (0.1, 3.9)), None)
    return Costmap.from_grid(grid, 0.105, CostmapConfig()), {"room": room}


def _scan(pose: Pose2D, beams: int = 180, range_max: float = 3.5) -> LaserScan:
    inner = (RESOLUTION, ROOM - RESOLUTION)
    angles = pose.yaw + np.linspace(-math.pi, math.pi, beams, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (inner[1] - pose.x) / c, (inner[0] - pose.x) / c)
        ty = np.where(s > 0, (inner[1] - pose.y) / s, (inner[0] - pose.y) / s)
    ranges = np.minimum(np.abs(tx), np.abs(ty))
    ranges = np.where(ranges <= range_max, ranges, np.inf).astype(np.float32)
    return LaserScan(ranges, -math.pi, 2 * math.pi / beams, 0.12, range_max, 0.0)


def sample_context() -> TreeContext:
    """A burger in the 4 m room with a real navigator (cost_grid, pure_pursuit)."""
    robot = BUILTIN_ROBOTS["burger"]
    costmap, rooms = _room()
    limits = VelocityLimits(
        max_v=robot.max_linear_velocity,
        max_w=robot.max_angular_velocity,
        max_acc_v=robot.max_linear_acceleration,
        max_acc_w=robot.max_angular_acceleration,
    )
    gp = registry.config("global_planner", "cost_grid")(type="cost_grid")
    lp = registry.config("local_planner", "pure_pursuit")(type="pure_pursuit")
    nav = NavigationConfig()
    navigator = Navigator(
        ObstacleLayer(costmap, costmap.config.obstacles),
        registry.create("global_planner", gp),
        registry.create(
            "local_planner", lp, limits=limits, robot_radius=robot.footprint_radius,
            control_period=PERIOD,
        ),
        limits, nav, PERIOD,
    )  # fmt: skip
    start = Pose2D(1.0, 1.0, 0.0)
    handle = RobotHandle(RobotState(0.0, start, scan=_scan(start)), navigator, rooms=rooms)
    return TreeContext(handle, robot, nav, {"room": Pose2D(2.0, 2.0, 0.0)})


def build(cls: type, ports: NodePorts, context: TreeContext) -> py_trees.behaviour.Behaviour:
    """An instance as the assembly builds it (a leaf as the child of others)."""
    kwargs = {k: getattr(ports, k) for k in type(ports).model_fields if k != "type"}
    params = inspect.signature(cls.__init__).parameters
    if "context" in params:
        kwargs["context"] = context
    if ports.kind in ("control", "decorator") and "handle" in params:
        kwargs["handle"] = context.handle
    if ports.kind == "control":
        leaves = [py_trees.behaviours.Success("a"), py_trees.behaviours.Running("b")]
        return cls("node", leaves, **kwargs)
    if ports.kind == "decorator":
        return cls("node", py_trees.behaviours.Running("child"), **kwargs)
    return cls("node", context.handle, **kwargs)


def _advance(handle: RobotHandle) -> None:
    """Move the robot as commanded for one step (a unicycle, no physics)."""
    state = handle.state
    v, w = handle.command
    est = state.estimate
    state.estimate = Pose2D(
        est.x + v * PERIOD * math.cos(est.yaw), est.y + v * PERIOD * math.sin(est.yaw),
        est.yaw + w * PERIOD,
    )  # fmt: skip
    state.time += PERIOD
    state.scan = _scan(state.estimate)
    handle.stop()


def check_node(cls: type, ports: NodePorts | None = None) -> None:
    """Raise :class:`NodeCheckError` unless ``cls`` is a working node type."""
    problems = static_problems(cls)
    if problems:
        raise NodeCheckError(_message(cls, problems))
    config: type[NodePorts] = cls.Config  # type: ignore[attr-defined]
    name = typing.get_args(config.model_fields["type"].annotation)[0]
    if ports is None:
        example = getattr(config, "example", {})
        if example is None:
            return
        ports = config.model_validate({"type": name, **example})
    context = sample_context()
    try:
        node = build(cls, ports, context)
        for tick in range(TICKS):
            node.tick_once()
            if node.status not in (Status.SUCCESS, Status.FAILURE, Status.RUNNING):
                raise NodeCheckError(f"tick {tick + 1} left the status {node.status}")
            if config.kind == "condition" and node.status is Status.RUNNING:
                raise NodeCheckError("a condition must succeed or fail in one tick")
            if node.status is not Status.RUNNING:
                break
            _advance(context.handle)
        if node.status is Status.RUNNING:
            node.stop(Status.INVALID)
            if context.handle.navigator.status is NavStatus.RUNNING:
                raise NodeCheckError("halted while running, it left the navigator driving")
    except NodeCheckError as exc:
        raise NodeCheckError(_message(cls, [str(exc)])) from None
    except Exception as exc:
        raise NodeCheckError(_message(cls, [f"raised {type(exc).__name__}: {exc}"])) from exc


def _message(cls: type, problems: list[str]) -> str:
    return f"{cls.__qualname__} is not a working behavior node:\n" + "\n".join(
        f"  - {p}" for p in problems
    )


__all__ = ["NodeCheckError", "check_node", "sample_context", "static_problems"]
