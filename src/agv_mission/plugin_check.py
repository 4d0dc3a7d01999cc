"""``check_plugin``: does a plugin class keep its slot's contract? (like gymnasium's
``check_env``)

Plugin authors call it in their tests::

    from agv_mission.plugin_check import check_plugin
    check_plugin(MyRrt)  # the slot is inferred, or check_plugin(MyRrt, "global_planner")

It checks the config (a :class:`~agv_mission.registry.PluginConfig` whose ``type`` is the
plugin's name, buildable from defaults), that every method of the slot's protocol is there
with the protocol's parameters, and then drives one instance in a 4 m x 4 m walled room:
a plan across it, a control step, a localisation or SLAM update with a real scan, a task
dispatched among three robots, traffic decisions for two robots meeting head-on.
"""

from __future__ import annotations

import inspect
import math
from typing import Any

import numpy as np

from agv_mission.behaviors.check import NodeCheckError, check_node
from agv_mission.fleet.base import (
    Assignment,
    Dispatcher,
    DispatchError,
    FleetTask,
    RobotWork,
    TrafficController,
    TrafficDecision,
    TrafficRobot,
    TrafficUpdate,
)
from agv_mission.geometry import Pose2D
from agv_mission.localization.base import Localizer, LocalizerDiagnostics
from agv_mission.mapping.base import Slam
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.planners.base import (
    GlobalPlanner,
    LocalPlanner,
    PlannedPath,
    PlanningError,
    VelocityCommand,
    VelocityLimits,
)
from agv_mission.registry import SLOTS, PluginConfig
from agv_mission.sensor_msgs import LaserScan

PROTOCOLS: dict[str, type] = {
    "global_planner": GlobalPlanner,
    "local_planner": LocalPlanner,
    "localization": Localizer,
    "slam": Slam,
    "dispatcher": Dispatcher,
    "traffic": TrafficController,
}
ROOM = 4.0  # metres, the side of the test room
RESOLUTION = 0.05
ROBOT_RADIUS = 0.1


class PluginCheckError(AssertionError):
    """The plugin breaks its slot's contract; the message lists how."""


def check_plugin(cls: type, slot: str | None = None, config: PluginConfig | None = None) -> None:
    """Raise :class:`PluginCheckError` unless ``cls`` is a working plugin of ``slot``.

    ``config``: the configuration to drive it with (default: ``cls.Config()``).
    """
    slot = slot or _infer_slot(cls)
    if slot == "behavior":
        _check_node(cls, config)
        return
    if slot not in SLOTS:
        raise ValueError(f"unknown slot {slot!r}; slots are {', '.join(SLOTS)}")
    problems = _static_problems(cls, slot)
    if problems:
        raise PluginCheckError(_message(cls, slot, problems))
    config = config if config is not None else cls.Config()
    try:
        _DRIVERS[slot](cls, config)
    except PluginCheckError as exc:
        raise PluginCheckError(_message(cls, slot, [str(exc)])) from None
    except Exception as exc:
        problem = f"raised {type(exc).__name__}: {exc}"
        raise PluginCheckError(_message(cls, slot, [problem])) from exc


def _check_node(cls: type, config: PluginConfig | None) -> None:
    try:
        check_node(cls, config)  # type: ignore[arg-type]
    except NodeCheckError as exc:
        raise PluginCheckError(str(exc)) from None


def _message(cls: type, slot: str, problems: list[str]) -> str:
    return f"{cls.__qualname__} is not a working {slot} plugin:\n" + "\n".join(
        f"  - {p}" for p in problems
    )


def _infer_slot(cls: type) -> str:
    if isinstance(getattr(cls, "Config", None), type) and hasattr(cls.Config, "kind"):
        return "behavior"
    for slot, methods in (
        ("global_planner", ("plan",)),
        ("local_planner", ("compute",)),
        ("slam", ("occupancy_grid",)),
        ("localization", ("request_nomotion_update",)),
        ("dispatcher", ("assign",)),
        ("traffic", ("decide",)),
    ):
        if all(callable(getattr(cls, m, None)) for m in methods):
            return slot
    raise PluginCheckError(f"{cls.__qualname__} has the methods of no plugin slot")


def _protocol_members(protocol: type) -> dict[str, Any]:
    return {
        name: value
        for name, value in vars(protocol).items()
        if not name.startswith("_") and (callable(value) or isinstance(value, property))
    }


def _static_problems(cls: type, slot: str) -> list[str]:
    problems: list[str] = []
    config = vars(cls).get("Config") or getattr(cls, "Config", None)
    if not (isinstance(config, type) and issubclass(config, PluginConfig)):
        problems.append("Config must be a subclass of agv_mission.registry.PluginConfig")
    else:
        field = config.model_fields.get("type")
        if field is None or not isinstance(field.default, str):
            problems.append("Config needs a 'type' field defaulting to the plugin's name")
        else:
            try:
                config()
            except Exception as exc:
                problems.append(f"Config() fails with defaults: {exc}")
    for name, member in _protocol_members(PROTOCOLS[slot]).items():
        mine = inspect.getattr_static(cls, name, None)
        if mine is None:
            problems.append(f"missing {name} (the {slot} protocol has it)")
        elif isinstance(member, property):
            continue
        elif callable(member) and callable(mine):
            want = list(inspect.signature(member).parameters)
            have = list(inspect.signature(mine).parameters)
            if have[: len(want)] != want:
                problems.append(f"{name}{inspect.signature(mine)}: expected parameters {want}")
    return problems


def _room() -> OccupancyGrid:
    n = int(round(ROOM / RESOLUTION))
    data = np.full((n, n), FREE, dtype=np.int8)
    data[[0, -1], :] = OCCUPIED
    data[:, [0, -1]] = OCCUPIED
    return OccupancyGrid(data, RESOLUTION, Pose2D(0.0, 0.0, 0.0))


def _scan(pose: Pose2D, beams: int = 180, range_max: float = 3.5) -> LaserScan:
    """The ranges a lidar at ``pose`` measures to the room's inner walls."""
    inner = (RESOLUTION, ROOM - RESOLUTION)
    angles = pose.yaw + np.linspace(-math.pi, math.pi, beams, endpoint=False)
    c, s = np.cos(angles), np.sin(angles)
    with np.errstate(divide="ignore"):
        tx = np.where(c > 0, (inner[1] - pose.x) / c, (inner[0] - pose.x) / c)
        ty = np.where(s > 0, (inner[1] - pose.y) / s, (inner[0] - pose.y) / s)
    ranges = np.minimum(np.abs(tx), np.abs(ty))
    ranges = np.where(ranges <= range_max, ranges, np.inf).astype(np.float32)
    return LaserScan(ranges, -math.pi, 2 * math.pi / beams, 0.12, range_max, 0.0)


def _expect(ok: bool, problem: str) -> None:
    if not ok:
        raise PluginCheckError(problem)


def _drive_global_planner(cls: type, config: PluginConfig) -> None:
    planner = cls(config)
    costmap = Costmap.from_grid(_room(), ROBOT_RADIUS, CostmapConfig())
    start, goal = Pose2D(1.0, 1.0, 0.0), Pose2D(3.0, 3.0, 0.0)
    path = planner.plan(costmap, start, goal, seed=0)
    _expect(isinstance(path, PlannedPath), "plan() must return a PlannedPath")
    pts = np.asarray(path.points, dtype=float)
    _expect(pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 2, "points must be (N>=2, 2)")
    _expect(np.hypot(*(pts[0] - (1.0, 1.0))) < 0.1, "the path must start at the start")
    _expect(np.hypot(*(pts[-1] - (3.0, 3.0))) < 0.1, "the path must end at the goal")
    _expect(bool(np.all(costmap.is_free(pts))), "the path's points must be free")
    _expect(float(planner.clearance) >= 0.0, "clearance must be a margin >= 0 m")
    try:
        planner.plan(costmap, start, Pose2D(0.0, 2.0, 0.0), seed=0)
    except PlanningError:
        pass
    else:
        raise PluginCheckError("a goal inside a wall must raise PlanningError")
    _expect(isinstance(planner.diagnostics(), dict), "diagnostics() must return a dict")


def _drive_local_planner(cls: type, config: PluginConfig) -> None:
    limits = VelocityLimits(max_v=0.22, max_w=2.84, max_acc_v=2.5, max_acc_w=3.2)
    planner = cls(config, limits=limits, robot_radius=ROBOT_RADIUS, control_period=0.1)
    planner.reset()
    path = np.array([[1.0, 2.0], [2.0, 2.0], [3.0, 2.0]])
    cmd = planner.compute(
        Pose2D(1.0, 2.0, 0.0), (0.0, 0.0), path, Pose2D(3.0, 2.0, 0.0), np.zeros((0, 2))
    )
    _expect(isinstance(cmd, VelocityCommand), "compute() must return a VelocityCommand")
    _expect(math.isfinite(cmd.v) and math.isfinite(cmd.w), "the command must be finite")
    _expect(abs(cmd.v) <= limits.max_v + 1e-6, "v must stay within the limits")
    _expect(abs(cmd.w) <= limits.max_w + 1e-6, "w must stay within the limits")
    _expect(isinstance(planner.diagnostics(), dict), "diagnostics() must return a dict")


def _drive_localization(cls: type, config: PluginConfig) -> None:
    localizer = cls(config, grid=_room(), rng=np.random.default_rng(0))
    pose = Pose2D(2.0, 2.0, 0.3)
    localizer.reset(pose, Pose2D(0.0, 0.0, 0.0))
    localizer.request_nomotion_update()
    for i in range(3):
        est = localizer.update(Pose2D(0.0, 0.0, 0.0), _scan(pose), pose, 0.2 * i)
        _expect(isinstance(est, Pose2D), "update() must return a Pose2D")
        _expect(all(math.isfinite(v) for v in (est.x, est.y, est.yaw)), "the estimate is NaN")
    _expect(math.hypot(est.x - 2.0, est.y - 2.0) < 0.5, "the estimate left a robot standing still")
    diag = localizer.diagnostics()
    _expect(isinstance(diag, LocalizerDiagnostics), "diagnostics() must be LocalizerDiagnostics")


def _drive_slam(cls: type, config: PluginConfig) -> None:
    slam = cls(config, bounds=(0.0, ROOM, 0.0, ROOM), rng=np.random.default_rng(0))
    pose = Pose2D(2.0, 2.0, 0.0)
    slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
    for i in range(3):
        est = slam.update(Pose2D(0.0, 0.0, 0.0), _scan(pose), pose, 0.2 * i)
        _expect(isinstance(est, Pose2D), "update() must return a Pose2D")
    grid = slam.occupancy_grid()
    _expect(isinstance(grid, OccupancyGrid), "occupancy_grid() must return an OccupancyGrid")
    _expect(bool(np.any(grid.data != UNKNOWN)), "three scans mapped nothing")
    _expect(slam.integrations >= 1, "integrations must count the scans added")
    _expect(np.asarray(slam.covariance).shape == (3, 3), "covariance must be 3x3")
    _expect(isinstance(slam.pose, Pose2D), "pose must be a Pose2D")
    _expect(isinstance(slam.diagnostics(), dict), "diagnostics() must return a dict")
    slam.finish()
    moved = slam.reframe(Pose2D(0.0, 0.0, 0.0))
    _expect(isinstance(moved, bool), "reframe() must say whether the map moved (a bool)")
    _expect(isinstance(slam.occupancy_grid(), OccupancyGrid), "no map after finish/reframe")


def _drive_dispatcher(cls: type, config: PluginConfig) -> None:
    dispatcher = cls(config)
    speed = 0.2  # m/s

    def travel(name: str, a: Pose2D, b: Pose2D) -> float:
        return a.distance_to(b) / speed

    robots = [
        RobotWork("near_busy", Pose2D(1.0, 1.0), held_time=30.0),
        RobotWork("far_idle", Pose2D(3.0, 3.0)),
        RobotWork("out", Pose2D(1.0, 1.2), available=False),
    ]
    task = FleetTask("t0", (Pose2D(1.5, 1.0), Pose2D(2.0, 1.0)))
    got = dispatcher.assign(task, robots, travel)
    _expect(isinstance(got, Assignment), "assign() must return an Assignment")
    _expect(got.robot in {"near_busy", "far_idle"}, f"assign() chose {got.robot!r}")
    _expect(math.isfinite(got.finish) and got.finish >= 0.0, "finish must be seconds >= 0")
    again = dispatcher.assign(task, robots, travel)
    _expect(again.robot == got.robot, "the same question must get the same answer")
    try:
        dispatcher.assign(task, [RobotWork("out", Pose2D(1.0, 1.0), available=False)], travel)
    except DispatchError:
        pass
    else:
        raise PluginCheckError("a task no available robot can do must raise DispatchError")


def _drive_traffic(cls: type, config: PluginConfig) -> None:
    traffic = cls(config)
    costmap = Costmap.from_grid(_room(), ROBOT_RADIUS, CostmapConfig())
    line = np.array([[0.8, 2.0], [3.2, 2.0]])

    def robot(name: str, x: float, path: np.ndarray) -> TrafficRobot:
        yaw = 0.0 if path[-1, 0] > x else math.pi
        return TrafficRobot(
            name, Pose2D(x, 2.0, yaw), ROBOT_RADIUS, 0.22, 0.2, path, False, costmap
        )

    alone = traffic.decide(0.0, [robot("a", 1.0, line)])
    _expect(isinstance(alone, TrafficUpdate), "decide() must return a TrafficUpdate")
    _expect(alone.decisions["a"].action == "go", "a robot alone on its path must go")
    for step in range(1, 4):  # head-on, 0.6 m apart (0.39 m between the footprints)
        a, b = robot("a", 1.7, line), robot("b", 2.3, line[::-1].copy())
        update = traffic.decide(0.1 * step, [a, b])
        _expect(set(update.decisions) == {"a", "b"}, "every robot needs a decision")
        ahead = 0.0
        for d in update.decisions.values():
            _expect(isinstance(d, TrafficDecision), "decisions must be TrafficDecisions")
            _expect(d.action in ("go", "wait", "yield", "replan"), f"unknown action {d.action}")
            if d.action == "go":
                ahead += math.inf if d.limit is None else max(d.limit, 0.0)
        _expect(ahead <= 0.39, "two robots head-on were both let go into each other")
        _expect(all(isinstance(e, dict) and "event" in e for e in update.events), "events")
    stats = traffic.stats()
    _expect(isinstance(stats, dict) and {"waits", "deadlocks"} <= set(stats), "stats() keys")


_DRIVERS = {
    "global_planner": _drive_global_planner,
    "local_planner": _drive_local_planner,
    "localization": _drive_localization,
    "slam": _drive_slam,
    "dispatcher": _drive_dispatcher,
    "traffic": _drive_traffic,
}
