"""The handle behaviours hold: the robot's state, its navigator and its command slot."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agv_mission.geometry import Pose2D
from agv_mission.maps.docks import Dock
from agv_mission.maps.recorder import LocationRecorder
from agv_mission.maps.rooms import Room
from agv_mission.navigation.navigator import Navigator
from agv_mission.navigation.state import RobotState
from agv_mission.robots.battery import Battery


@dataclass
class RobotHandle:
    """Everything a behaviour may touch. The runner refreshes ``state`` before each tick,
    clears ``command`` to a stop, and sends whatever the tick left in ``command``."""

    state: RobotState
    navigator: Navigator
    command: tuple[float, float] = (0.0, 0.0)
    events: list[dict[str, Any]] = field(default_factory=list)
    rooms: dict[str, Room] = field(default_factory=dict)
    recorders: list[LocationRecorder] = field(default_factory=list)
    recorded: dict[str, Pose2D] = field(default_factory=dict)
    nomotion_update: bool = False  # ask the localiser to update with the next scan
    remote_command: tuple[float, float] | None = None  # (v, w) a remote driver sends
    remote_goal: Pose2D | None = None  # a teleop task drives here first ("2D Nav Goal")
    battery: Battery | None = None  # None: the robot's battery is not modelled
    docks: dict[str, Dock] = field(default_factory=dict)  # the world's and rooms file's
    docked: Dock | None = None  # the dock the robot stands on (Dock sets, Undock clears)
    remote_goal_tolerance: tuple[float | None, float | None] = (None, None)  # xy m, yaw rad
    remote_speed_limit: float | None = None  # m/s cap while driving to ``remote_goal``

    def drive(self, v: float, w: float) -> None:
        self.command = (float(v), float(w))

    def stop(self) -> None:
        self.command = (0.0, 0.0)

    def record(self, label: str) -> Pose2D:
        """Record the estimated pose under ``label`` in every recorder file, atomically."""
        pose = self.state.estimate
        for recorder in self.recorders:
            recorder.record(label, pose)
        self.recorded[label] = pose
        return pose

    def log(self, event: str, **details: Any) -> None:
        """Record something that happened, stamped with simulated time."""
        self.events.append({"t": round(self.state.time, 3), "event": event, **details})

    def log_recorded(self, label: str, pose: Pose2D, **details: Any) -> None:
        """The ``room_recorded`` event every way of recording a room logs (the run's
        report and the live stream read it)."""
        self.log(
            "room_recorded",
            room=label,
            x=round(pose.x, 4),
            y=round(pose.y, 4),
            yaw=round(pose.yaw, 4),
            **details,
        )
