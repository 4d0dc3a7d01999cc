"""The handle behaviours hold: the robot's state, its navigator and its command slot."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from agv_mission.navigation.navigator import Navigator
from agv_mission.navigation.state import RobotState


@dataclass
class RobotHandle:
    """Everything a behaviour may touch. The runner refreshes ``state`` before each tick,
    clears ``command`` to a stop, and sends whatever the tick left in ``command``."""

    state: RobotState
    navigator: Navigator
    command: tuple[float, float] = (0.0, 0.0)
    events: list[dict[str, Any]] = field(default_factory=list)

    def drive(self, v: float, w: float) -> None:
        self.command = (float(v), float(w))

    def stop(self) -> None:
        self.command = (0.0, 0.0)

    def log(self, kind: str, **details: Any) -> None:
        """Record something that happened, stamped with simulated time."""
        self.events.append({"t": round(self.state.time, 3), "event": kind, **details})
