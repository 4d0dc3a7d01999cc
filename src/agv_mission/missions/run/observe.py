"""Watching and steering a run: the hooks every front door uses.

An observer sees a run start, every control step (as a :class:`StepSample`) and the end;
a control is asked before every step and may pause, cancel, or set a remote command. The
runner builds samples only when at least one observer is attached, so a plain run pays
nothing for them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.rooms import Room
from agv_mission.missions.load.schema import Mission
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.robot_run import RobotRun
from agv_mission.missions.run.samples import StepSample, TreeNode
from agv_mission.navigation.handle import RobotHandle
from agv_mission.robots.description import RobotDescription
from agv_mission.world.simulation import SimulatedWorld


@dataclass(frozen=True)
class RobotStart:
    """One robot of a run, as it starts."""

    name: str  # its ROS namespace in a fleet mission
    robot: RobotDescription
    start: Pose2D
    tree_nodes: list[TreeNode]  # pre-order
    keepout_mask: OccupancyGrid | None = None  # the keepout filter mask (100: kept out)
    speed_mask: OccupancyGrid | None = None  # the speed filter mask (% of max speed, 0: none)


@dataclass(frozen=True)
class RunStart:
    """What does not change during a run."""

    run_dir: Path | None
    mission: Mission  # the resolved mission model
    world_map: OccupancyGrid  # the known map (the mission's map:, else the world's)
    rooms: dict[str, Room]  # label -> Room (polygon, anchor)
    robots: list[RobotStart]  # every robot; a one-robot mission's one
    docks: dict[str, Dock] = field(default_factory=dict)  # chargers by name
    fleet: bool = False  # a fleet mission (robots: list): per-robot names are namespaces

    # A one-robot mission's robot (the first robot of a fleet).
    @property
    def robot(self) -> RobotDescription:
        return self.robots[0].robot

    @property
    def start(self) -> Pose2D:
        return self.robots[0].start

    @property
    def tree_nodes(self) -> list[TreeNode]:
        return self.robots[0].tree_nodes

    @property
    def keepout_mask(self) -> OccupancyGrid | None:
        return self.robots[0].keepout_mask

    @property
    def speed_mask(self) -> OccupancyGrid | None:
        return self.robots[0].speed_mask


class RunObserver(Protocol):
    """Sees a run: its start, every control step, its record at the end (once)."""

    def on_start(self, start: RunStart) -> None: ...

    def on_step(self, sample: StepSample) -> None: ...

    def on_end(self, record: RunRecord) -> None: ...


class LiveRun(Protocol):
    """What a :class:`RunControl` may read and steer of a run between two steps (the
    runner's ``MissionRun`` is one)."""

    world: SimulatedWorld
    status: str | None  # None while it runs

    @property
    def by_name(self) -> Mapping[str, RobotRun]: ...

    @property
    def lead(self) -> RobotRun: ...  # the first robot (a one-robot mission's only one)

    @property
    def handle(self) -> RobotHandle: ...  # the first robot's

    def cancel(self, reason: str) -> None: ...

    def end(self, status: str, reason: str | None) -> bool: ...


class RunControl(Protocol):
    """Steers a run between control steps."""

    def before_step(self, run: LiveRun) -> None:
        """Called before every control step; may block (pause), may call
        ``run.cancel(reason)`` (the run ends ``aborted``), may set a robot's
        ``handle.remote_command = (v, w)`` for a teleop task (``run.handle``: the first
        robot's). A control class with ``only_cancels = True`` promises it never commands
        a robot, so a fleet's robots may decide in other processes (missions.run.team)."""
        ...
