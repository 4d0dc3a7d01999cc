"""What the fleet plugins speak: robots' work and state in, assignments and decisions out.

The run (``missions/``) gathers these from every robot once per control step and hands
each robot's navigator its :class:`TrafficDecision`; the fleet layer never touches a
robot, a navigator or the world.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal, Protocol

import numpy as np

from agv_mission.geometry import Pose2D

if TYPE_CHECKING:  # a costmap's module brings scipy: the schema (fleet configs) needs none
    from agv_mission.maps.costmap import Costmap

FleetEvent = dict[str, Any]
"""One fleet event, as the run logs it: ``{"event": "wait" | "wait_end" | "deadlock" |
"yield_end" | "dispatch", "t": seconds, "robot": name, ...}``."""

TravelTime = Callable[[str, Pose2D, Pose2D], float]
"""Seconds robot ``name`` needs from one pose to another (``math.inf``: unreachable)."""


class DispatchError(RuntimeError):
    """No robot can do the task; the message says why."""


# ------------------------------------------------------------------------- dispatch


@dataclass(frozen=True)
class RobotWork:
    """What a dispatcher knows of one robot when a task is released."""

    name: str
    end: Pose2D  # where the work it holds ends (its pose when it holds none)
    held_time: float = 0.0  # seconds of work it holds: its own tasks' rest + queued tasks
    available: bool = True  # False: it takes no new task (failed, out of service)

    @property
    def idle(self) -> bool:
        return self.held_time <= 0.0


@dataclass(frozen=True)
class FleetTask:
    """A task to dispatch: its id, the poses it visits in order, and the seconds spent
    at them beyond travel (waits, docking)."""

    id: str
    goals: tuple[Pose2D, ...]
    work_time: float = 0.0


@dataclass(frozen=True)
class Assignment:
    """A dispatcher's answer: the robot, when it would be done (seconds from now), and
    every robot's bid (``math.inf``: it cannot do the task)."""

    robot: str
    finish: float
    bids: dict[str, float] = field(default_factory=dict)


class Dispatcher(Protocol):
    """Picks the robot for a task that names none. Built as ``cls(config)``."""

    def assign(
        self, task: FleetTask, robots: Sequence[RobotWork], travel_time: TravelTime
    ) -> Assignment:
        """The robot that gets ``task``; raises :class:`DispatchError` when none can."""
        ...


# ------------------------------------------------------------------------- traffic


@dataclass(frozen=True, eq=False)
class TrafficRobot:
    """One robot as the traffic layer sees it in one control step."""

    name: str
    pose: Pose2D  # its estimate, map frame
    radius: float  # footprint radius, m
    max_speed: float  # m/s
    speed: float = 0.0  # m/s now
    path: np.ndarray | None = None  # (k, 2) rest of its plan, map frame; None: no plan
    idle: bool = False  # no goal: parked, or its tree is done
    costmap: Costmap | None = None  # its static costmap, searched for a detour pose


Action = Literal["go", "wait", "yield", "replan"]


@dataclass(frozen=True, eq=False)
class TrafficDecision:
    """What one robot's navigator is told for this control step.

    * ``go``: follow the plan, at most ``limit`` metres further along it (None: no limit).
    * ``wait``: stand still, keep the plan (no 'no progress' recovery while waiting).
    * ``yield``: drive to ``detour`` (at most ``limit`` metres along the way there), stay
      there while told so, then resume the goal.
    * ``replan``: plan again with ``avoid`` points as lethal cells (the others' reserved
      space, also as ``avoid_polygons``), then go.
    """

    action: Action = "go"
    limit: float | None = None
    detour: Pose2D | None = None
    avoid: np.ndarray | None = None  # (k, 2) points covering the space to keep out of
    avoid_polygons: tuple[Any, ...] = ()  # shapely polygons of the same space
    blocker: str | None = None  # the robot this one waits for or yields to
    reason: str = ""


GO = TrafficDecision()


@dataclass
class TrafficUpdate:
    """One step's decisions (every robot named) and the events it raised."""

    decisions: dict[str, TrafficDecision]
    events: list[FleetEvent] = field(default_factory=list)


class TrafficController(Protocol):
    """Keeps robots out of each other's way. Built as ``cls(config)``; ``decide`` is
    called once per control step with every robot, on the simulation clock ``t``."""

    def decide(self, t: float, robots: Sequence[TrafficRobot]) -> TrafficUpdate: ...

    def stats(self) -> dict[str, Any]:
        """``{"waits": {"count", "time"}, "deadlocks": n}`` so far."""
        ...
