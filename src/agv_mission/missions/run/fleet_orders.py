"""The run's side of the fleet layer: dispatch when tasks are released, traffic every step.

* :func:`queue_fleet_tasks` releases the fleet's tasks when the run starts, in the order
  given: one with ``robot:`` queues on that robot, one without goes to the robot the
  mission's ``dispatcher`` picks (:func:`~agv_mission.fleet.release.release_tasks`, on
  the poses each task and each robot's own tasks drive to). Every robot's queue runs
  behind its own tree, through the one tree assembly.
* :class:`FleetCoordinator` runs once per control step before the robots' trees tick: it
  knows each robot as a :class:`FleetMember` (name, body, top speed, costmap) and reads
  its :class:`~agv_mission.missions.run.samples.RobotReport` of the step before (estimate,
  speed, the path its navigator drives, whether it is busy), asks the ``traffic`` plugin,
  and answers with a :class:`FleetOrder` per robot: the decision for its navigator, the
  others' bodies (which its obstacle layer must not mark) and its fleet events. It never
  touches a robot: each robot takes its own order.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from agv_mission.fleet.base import TrafficDecision, TrafficRobot
from agv_mission.fleet.release import Bidder, Release, release_tasks
from agv_mission.geometry import Pose2D
from agv_mission.missions.load.resolved import LoadedMission, RobotSetup
from agv_mission.missions.load.tree_assembly import assemble
from agv_mission.missions.load.tree_spec import NodeSpec, TreeSource, TreeSpec, Where
from agv_mission.registry import PluginConfig, registry

if TYPE_CHECKING:
    from agv_mission.maps.costmap import Costmap
    from agv_mission.missions.run.samples import RobotReport


def tree_goals(
    spec: TreeSpec, room_goals: dict[str, Pose2D], docks: dict[str, Any]
) -> list[Pose2D]:
    """The poses a tree's tasks drive to, in tree order (a patrol's waypoints once per
    loop, a visit's room entries, a dock's pose): what a dispatcher's estimate travels."""
    goals: list[Pose2D] = []
    for _, node in spec.nodes():
        ports = node.ports
        if ports is None:
            continue
        poses = [p.to_pose2d() for _, p in getattr(ports, "goal_poses", lambda: [])()]
        goals += poses * int(getattr(ports, "loops", 1) or 1)
        for _, room in getattr(ports, "rooms_visited", lambda: [])():
            if room in room_goals:
                goals.append(room_goals[room])
        dock = getattr(ports, "dock", None)
        if node.type == "dock" and isinstance(dock, str) and dock in docks:
            goals.append(docks[dock].pose)
    return goals


def queue_fleet_tasks(loaded: LoadedMission) -> tuple[LoadedMission, list[dict[str, Any]]]:
    """``loaded`` with every fleet task queued behind its robot's own tree, in the order of
    ``tasks:`` (assigned by ``robot:`` or dispatched), and the dispatch log ``[{task, type,
    robot, t, finish}]`` (``task``: its number in ``tasks:``, from 1 as every report counts
    tasks)."""
    queued: dict[str, list[NodeSpec]] = {s.name: [] for s in loaded.robots}
    log: list[dict[str, Any]] = []
    if any(t.robot is None for t in loaded.fleet_tasks):
        log = _dispatch(loaded, queued)
    else:
        for task in loaded.fleet_tasks:
            queued[task.robot or ""].append(task.tree.source.main.children[0])
    fleet = [_with_queue(s, queued[s.name], loaded) for s in loaded.robots]
    return dataclasses.replace(loaded, robots=fleet), log


def _dispatch(loaded: LoadedMission, queued: dict[str, list[NodeSpec]]) -> list[dict[str, Any]]:
    """Fill ``queued`` in the order of the fleet's tasks (:func:`release_tasks`: assigned
    ones on their robot, the others on the dispatcher's pick); the dispatch log. A
    dispatched task's goals are those of the first robot's map (its rooms' entries)."""
    setups = {s.name: s for s in loaded.robots}
    bidders = [
        Bidder(s.name, s.start, _goals(s.tree, s, loaded), s.costmap, s.robot.max_linear_velocity)
        for s in loaded.robots
    ]
    releases = [
        Release(
            t.index, _goals(t.tree, setups[t.robot] if t.robot else loaded.lead, loaded), t.robot
        )
        for t in loaded.fleet_tasks
    ]
    log = []
    for task, went in zip(
        loaded.fleet_tasks,
        release_tasks(loaded.mission.fleet.dispatcher, bidders, releases),
        strict=True,
    ):
        queued[went.robot].append(task.tree.source.main.children[0])
        if went.finish is not None:
            log.append(
                {
                    "task": task.index + 1,
                    "type": task.type,
                    "robot": went.robot,
                    "t": 0.0,
                    "finish": round(went.finish, 1),
                }
            )
    return log


def _goals(tree: TreeSpec | None, setup: RobotSetup, loaded: LoadedMission) -> list[Pose2D]:
    return tree_goals(tree, setup.room_goals, loaded.docks) if tree is not None else []


def _with_queue(setup: RobotSetup, specs: list[NodeSpec], loaded: LoadedMission) -> RobotSetup:
    """``setup`` whose tree runs ``specs`` after its own; a robot with neither logs that it
    has nothing to do (and stands by for the traffic layer)."""
    own = setup.tree
    if not specs and own is not None:
        return setup
    if own is None:
        where = Where(str(loaded.source or loaded.name), ("robots",), None)
        idle = NodeSpec("log", where, None, {"message": f"{setup.name} has no tasks"})
        main = idle if not specs else NodeSpec("sequence", where, setup.name, {}, {}, specs)
        source = TreeSource(main, blackboard=dict(loaded.mission.blackboard))
    else:
        main = NodeSpec("sequence", own.source.main.where, setup.name, {}, {},
                        [own.source.main, *specs])  # fmt: skip
        source = dataclasses.replace(own.source, main=main)
    return dataclasses.replace(setup, tree=assemble(source))


@dataclasses.dataclass(frozen=True)
class FleetMember:
    """A robot as the fleet layer knows it for the whole run."""

    name: str
    radius: float  # m, its footprint's
    max_speed: float  # m/s, its top linear speed
    costmap: Costmap  # the one it plans on (the traffic plugin's reservations use it)


@dataclasses.dataclass
class FleetOrder:
    """One robot's part of a step's traffic decisions: what its navigator is told, the
    other robots' bodies (x, y, radius), and its fleet events (wait, yield, deadlock)."""

    decision: TrafficDecision
    bodies: np.ndarray
    events: list[dict[str, Any]]


class FleetCoordinator:
    """Asks the traffic plugin once per control step, on the robots' reports."""

    def __init__(self, members: Sequence[FleetMember], traffic: PluginConfig, log: dict) -> None:
        self.members = list(members)
        self.traffic = registry.create("traffic", traffic)
        self.log = log

    def decide(self, now: float, reports: Sequence[RobotReport]) -> dict[str, FleetOrder]:
        """Every robot's order for this step, from each member's latest report (in the
        members' order: those of the step before, as a fleet manager acts on the robots'
        last reports)."""
        states = [_state(m, r) for m, r in zip(self.members, reports, strict=True)]
        update = self.traffic.decide(now, states)
        bodies = np.array([[s.pose.x, s.pose.y, s.radius] for s in states])
        # each the others' rows: the same array np.delete(bodies, i, axis=0) makes, at a
        # third of its cost (its checks cost more than the copy of a few rows)
        orders = {
            m.name: FleetOrder(
                update.decisions[m.name], np.concatenate((bodies[:i], bodies[i + 1 :])), []
            )
            for i, m in enumerate(self.members)
        }
        for event in update.events:
            name = event.get("robot")
            if isinstance(name, str) and name in orders:
                orders[name].events.append(
                    {"t": event["t"], **{k: v for k, v in event.items() if k != "t"}}
                )
        stats = self.traffic.stats()
        self.log["waits"] = dict(stats["waits"])
        self.log["deadlocks"] = stats["deadlocks"]
        return orders


def _state(member: FleetMember, report: RobotReport) -> TrafficRobot:
    """A robot for the traffic plugin: what it is, and what it reported after deciding."""
    idle = report.status is not None or (not report.navigating and not report.yielding)
    return TrafficRobot(
        member.name,
        report.estimate,
        member.radius,
        member.max_speed,
        speed=float(report.command[0]),
        path=report.traffic_path,
        idle=idle,
        costmap=member.costmap,
    )
