"""The run's side of the fleet layer: dispatch when tasks are released, traffic every step.

* :func:`dispatch_tasks` hands every fleet task without ``robot:`` to the robot the
  mission's ``dispatcher`` picks, when the run starts (fleet tasks are released then, in
  the order given). A robot's bid counts the work it holds: its own tasks' goals (from
  where it starts), then the tasks already queued on it, travelled at its top speed over
  its free space (:class:`~agv_mission.fleet.travel.GridTravelTime`). The tasks a robot
  wins queue behind its own tree, through the one tree assembly.
* :class:`FleetCoordinator` runs once per control step before the robots' trees tick: it
  gathers each robot's estimate, speed and the path its navigator drives, asks the
  ``traffic`` plugin, hands every navigator its decision (and the others' bodies, which its
  obstacle layer must not mark), and logs the fleet's events to the robots' handles.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from agv_mission.fleet.base import FleetTask, RobotWork, TrafficRobot
from agv_mission.fleet.travel import GridTravelTime
from agv_mission.geometry import Pose2D
from agv_mission.missions.loader import LoadedMission, RobotSetup
from agv_mission.missions.robot_run import RobotRun
from agv_mission.missions.tree import NodeSpec, TreeSpec, assemble
from agv_mission.navigation.navigator import NavStatus
from agv_mission.registry import registry


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


def dispatch_tasks(loaded: LoadedMission) -> tuple[LoadedMission, list[dict[str, Any]]]:
    """``loaded`` with every dispatched fleet task queued behind its robot's tree, and the
    dispatch log ``[{task, type, robot, t, finish}]`` (``task``: its index in ``tasks:``)."""
    tasks = [t for t in loaded.fleet_tasks if t.robot is None]
    if not tasks:
        return loaded, []
    dispatcher = registry.create("dispatcher", loaded.mission.fleet.dispatcher)
    setups = {s.name: s for s in loaded.fleet}
    travel = {s.name: GridTravelTime(s.costmap, s.robot.max_linear_velocity) for s in loaded.fleet}

    def travel_time(name: str, a: Pose2D, b: Pose2D) -> float:
        return travel[name](a, b)

    work: dict[str, RobotWork] = {}
    for s in loaded.fleet:
        assert s.tree is not None, "a fleet robot has a tree"
        own = tree_goals(s.tree, s.room_goals, loaded.docks)
        held, here = 0.0, s.start
        for goal in own:
            held += travel_time(s.name, here, goal)
            here = goal
        work[s.name] = RobotWork(s.name, here, held if np.isfinite(held) else 0.0)
    queued: dict[str, list[NodeSpec]] = {name: [] for name in setups}
    log = []
    for task in tasks:
        winner_view = loaded.fleet[0]
        goals = tuple(tree_goals(task.tree, winner_view.room_goals, loaded.docks))
        got = dispatcher.assign(FleetTask(str(task.index), goals), list(work.values()), travel_time)
        queued[got.robot].append(task.tree.source.main.children[0])
        end = goals[-1] if goals else work[got.robot].end
        work[got.robot] = RobotWork(got.robot, end, got.finish)
        log.append(
            {
                "task": task.index,
                "type": task.type,
                "robot": got.robot,
                "t": 0.0,
                "finish": round(got.finish, 1),
            }
        )
    fleet = [_with_queue(s, queued[s.name]) for s in loaded.fleet]
    return dataclasses.replace(loaded, fleet=fleet, tree=fleet[0].tree), log


def _with_queue(setup: RobotSetup, specs: list[NodeSpec]) -> RobotSetup:
    """``setup`` whose tree runs ``specs`` after its own (as assigned tasks are)."""
    if not specs:
        return setup
    assert setup.tree is not None
    source = setup.tree.source
    own = source.main
    main = NodeSpec("sequence", own.where, f"{setup.name}_queue", {}, {}, [own, *specs])
    tree = assemble(dataclasses.replace(source, main=main))
    return dataclasses.replace(setup, tree=tree)


class FleetCoordinator:
    """Asks the traffic plugin once per control step and hands out its decisions."""

    def __init__(self, loaded: LoadedMission, robots: Sequence[RobotRun], log: dict) -> None:
        self.robots = list(robots)
        self.by_name = {r.name: r for r in self.robots}
        self.traffic = registry.create("traffic", loaded.mission.fleet.traffic)
        self.log = log

    def step(self, now: float) -> None:
        """Decide on the robots' latest estimates (those of the step before: the fleet
        layer, as a fleet manager, acts on the robots' last reports)."""
        states = [self._state(r) for r in self.robots]
        update = self.traffic.decide(now, states)
        bodies = np.array([[s.pose.x, s.pose.y, s.radius] for s in states])
        for i, r in enumerate(self.robots):
            nav = r.navigator
            nav.fleet_bodies = np.delete(bodies, i, axis=0)
            nav.obey(update.decisions[r.name], r.handle.state)
        for event in update.events:
            name = event.get("robot")
            target = self.by_name.get(name) if isinstance(name, str) else None
            if target is not None:
                target.handle.events.append(
                    {"t": event["t"], **{k: v for k, v in event.items() if k != "t"}}
                )
        stats = self.traffic.stats()
        self.log["waits"] = dict(stats["waits"])
        self.log["deadlocks"] = stats["deadlocks"]

    @staticmethod
    def _state(r: RobotRun) -> TrafficRobot:
        nav = r.navigator
        idle = r.status is not None or (nav.status is not NavStatus.RUNNING and not nav.yielding)
        return TrafficRobot(
            r.name,
            r.estimate,
            r.robot.footprint_radius,
            r.limits.max_v,
            speed=float(r.command[0]),
            path=nav.traffic_path(),
            idle=idle,
            costmap=r.setup.costmap,
        )
