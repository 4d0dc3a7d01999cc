"""Battery and dock behaviours (Nav2's ``IsBatteryLow``, ``IsBatteryCharging`` and docking
server, pyrobosim's chargers): conditions on the level, docking, charging, undocking.

Each takes ``(name, handle, **ports)``; ``PORTS`` lists its ports as
``name -> (type, default, description)`` (``...``: required). Conditions answer in one
tick and never run. A halted action stops the robot (and a halted ``Charge`` stops
charging).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import py_trees
from py_trees.common import Status

from agv_mission.geometry import Pose2D, wrap_angle
from agv_mission.maps.docks import STAGING_DISTANCE
from agv_mission.maps.docks import Dock as DockPose
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus

Ports = dict[str, tuple[type, Any, str]]

#: m/s of the straight final approach and of backing out (Nav2 docking's controller
#: drives up to 0.15 m/s; slower keeps the contacts gentle)
APPROACH_SPEED = 0.1
#: m short of the dock pose at which the robot counts as docked
DOCK_TOLERANCE = 0.02
#: m of lateral offset from the dock's axis beyond which docking fails
LATERAL_TOLERANCE = 0.05
#: m from the dock pose within which a docked robot can still charge
CHARGE_RANGE = 0.1
#: gains of the approach's line-following law (``w = -(K_LATERAL |v| y + K_HEADING yaw)``
#: about the dock's axis: critically damped at 0.1 m/s)
K_LATERAL, K_HEADING = 10.0, 2.0


class IsBatteryLow(py_trees.behaviour.Behaviour):
    """SUCCESS when the battery's level is at or below ``min_battery``, else FAILURE (a
    robot whose battery is not modelled is never low)."""

    PORTS: ClassVar[Ports] = {
        "min_battery": (float, ..., "battery level (0..1) at or below which it is low")
    }

    def __init__(
        self, name: str, handle: RobotHandle, *, min_battery: float, **_ros: object
    ) -> None:
        super().__init__(name)
        if not 0.0 <= min_battery <= 1.0:
            raise ValueError(f"min_battery must be within 0..1, got {min_battery}")
        self.handle = handle
        self.min_battery = float(min_battery)

    def update(self) -> Status:
        battery = self.handle.battery
        if battery is None:
            self.feedback_message = "no battery modelled"
            return Status.FAILURE
        self.feedback_message = f"level {battery.level:.3f}"
        return Status.SUCCESS if battery.level <= self.min_battery else Status.FAILURE


class IsBatteryCharging(py_trees.behaviour.Behaviour):
    """SUCCESS while the battery is being charged (a ``Charge`` on a dock), else FAILURE."""

    PORTS: ClassVar[Ports] = {}

    def __init__(self, name: str, handle: RobotHandle, **_ros: object) -> None:
        super().__init__(name)
        self.handle = handle

    def update(self) -> Status:
        battery = self.handle.battery
        charging = battery is not None and battery.charging
        return Status.SUCCESS if charging else Status.FAILURE


def _in_dock_frame(pose: Pose2D, dock: DockPose) -> tuple[float, float, float]:
    """(along, lateral, yaw) of ``pose`` in the dock's frame: ``along`` is 0 at the dock
    pose and -STAGING_DISTANCE at the staging pose."""
    rel = pose.relative_to(dock.pose)
    return rel.x, rel.y, wrap_angle(rel.yaw)


def _line_command(v: float, lateral: float, yaw: float, max_w: float) -> tuple[float, float]:
    """(v, w) that holds the robot on the dock's axis, driving forwards or backwards."""
    w = -(K_LATERAL * math.copysign(1.0, v) * lateral + K_HEADING * yaw)
    return v, max(-max_w, min(max_w, w))


class _Straight:
    """Time bound of a straight slow leg of ``distance`` m: three times the nominal."""

    @staticmethod
    def limit(distance: float) -> float:
        return 3.0 * abs(distance) / APPROACH_SPEED + 5.0


class Dock(py_trees.behaviour.Behaviour):
    """Dock at ``dock``: navigate to its staging pose with the robot's navigator, then
    drive straight and slowly onto it. SUCCESS once docked (charging is then possible);
    FAILURE when the staging pose cannot be reached, the approach misses the dock's axis
    or takes too long."""

    PORTS: ClassVar[Ports] = {"dock": (str, "charger", "the name of a dock of the world")}

    def __init__(self, name: str, handle: RobotHandle, *, dock: str = "charger") -> None:
        super().__init__(name)
        self.handle = handle
        self.dock = dock
        self._target: DockPose | None = None
        self._staging: Pose2D | None = None
        self._approaching = False
        self._deadline = 0.0

    def initialise(self) -> None:
        self.feedback_message = ""
        handle = self.handle
        self._target = handle.docks.get(self.dock)
        self._approaching = False
        if self._target is None or handle.docked is self._target:
            return
        handle.docked = None
        self._staging = self._target.staging()
        handle.navigator.start(self._staging, handle.state)

    def update(self) -> Status:
        handle, target = self.handle, self._target
        if target is None:
            known = ", ".join(sorted(handle.docks)) or "none"
            self.feedback_message = f"no dock named {self.dock!r} (docks: {known})"
            return Status.FAILURE
        if handle.docked is target:
            return Status.SUCCESS
        state = handle.state
        if not self._approaching:
            nav = handle.navigator
            if nav.goal is not self._staging:  # a halted node cancelled it: go on
                nav.start(self._staging, state)
            cmd = nav.update(state)
            handle.drive(cmd.v, cmd.w)
            if nav.status is NavStatus.FAILED:
                handle.stop()
                self.feedback_message = (
                    f"could not reach the staging pose of dock {self.dock!r}: "
                    f"{nav.reason or 'navigation failed'}"
                )
                return Status.FAILURE
            if nav.status is not NavStatus.SUCCEEDED:
                return Status.RUNNING
            self._approaching = True
            self._deadline = state.time + _Straight.limit(STAGING_DISTANCE)
            handle.log("dock_staged", dock=self.dock)
        along, lateral, yaw = _in_dock_frame(state.estimate, target)
        if along >= -DOCK_TOLERANCE:
            handle.stop()
            if abs(lateral) > LATERAL_TOLERANCE:
                self.feedback_message = (
                    f"missed dock {self.dock!r} by {abs(lateral):.3f} m sideways "
                    f"(tolerance {LATERAL_TOLERANCE} m)"
                )
                return Status.FAILURE
            handle.docked = target
            handle.log("docked", dock=self.dock, lateral=round(lateral, 4))
            return Status.SUCCESS
        if state.time > self._deadline:
            handle.stop()
            self.feedback_message = f"the final approach to dock {self.dock!r} took too long"
            return Status.FAILURE
        v = min(APPROACH_SPEED, max(0.03, -along))
        handle.drive(*_line_command(v, lateral, yaw, handle.navigator.limits.max_w))
        self.feedback_message = f"approach: {-along:.2f} m to go"
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            nav = self.handle.navigator
            if self._staging is not None and nav.goal is self._staging:
                nav.cancel()
            self.handle.stop()


class Undock(py_trees.behaviour.Behaviour):
    """Back straight out of the dock to its staging pose. FAILURE when not docked."""

    PORTS: ClassVar[Ports] = {}

    def __init__(self, name: str, handle: RobotHandle) -> None:
        super().__init__(name)
        self.handle = handle
        self._dock: DockPose | None = None
        self._deadline = 0.0

    def initialise(self) -> None:
        self.feedback_message = ""
        handle = self.handle
        self._dock = handle.docked
        handle.docked = None  # backing out: no more charging
        self._deadline = handle.state.time + _Straight.limit(STAGING_DISTANCE)

    def update(self) -> Status:
        handle, dock = self.handle, self._dock
        if dock is None:
            self.feedback_message = "not docked"
            return Status.FAILURE
        state = handle.state
        along, lateral, yaw = _in_dock_frame(state.estimate, dock)
        if along <= -STAGING_DISTANCE:
            handle.stop()
            handle.log("undocked", dock=dock.name)
            return Status.SUCCESS
        if state.time > self._deadline:
            handle.stop()
            self.feedback_message = f"backing out of dock {dock.name!r} took too long"
            return Status.FAILURE
        handle.drive(*_line_command(-APPROACH_SPEED, lateral, yaw, handle.navigator.limits.max_w))
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self.handle.stop()


class Charge(py_trees.behaviour.Behaviour):
    """Stand on the dock while the battery charges at its ``charge_power``; SUCCESS once
    the level reaches ``until``, FAILURE when the robot is not docked (or has no
    battery)."""

    PORTS: ClassVar[Ports] = {"until": (float, 1.0, "battery level (0..1) to charge to")}

    def __init__(self, name: str, handle: RobotHandle, *, until: float = 1.0) -> None:
        super().__init__(name)
        if not 0.0 < until <= 1.0:
            raise ValueError(f"until must be within (0, 1], got {until}")
        self.handle = handle
        self.until = float(until)

    def initialise(self) -> None:
        self.feedback_message = ""

    def update(self) -> Status:
        handle, battery = self.handle, self.handle.battery
        if battery is None:
            self.feedback_message = "the robot has no battery to charge"
            return Status.FAILURE
        dock = handle.docked
        if dock is None:
            battery.charging = False
            self.feedback_message = "not docked"
            return Status.FAILURE
        est = handle.state.estimate
        if math.hypot(est.x - dock.pose.x, est.y - dock.pose.y) > CHARGE_RANGE:
            battery.charging = False
            handle.docked = None
            self.feedback_message = f"the robot left dock {dock.name!r}"
            return Status.FAILURE
        handle.stop()
        if battery.level >= self.until - 1e-9:
            if battery.charging:
                handle.log("charged", dock=dock.name, level=round(battery.level, 4))
            battery.charging = False
            return Status.SUCCESS
        if not battery.charging:
            handle.log("charging", dock=dock.name, level=round(battery.level, 4))
        battery.charging = True
        self.feedback_message = f"level {battery.level:.3f} -> {self.until:g}"
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        battery = self.handle.battery
        if battery is not None:
            battery.charging = False
        if new_status is Status.INVALID:
            self.handle.stop()


from agv_mission.behaviors.ports.conditions import IsBatteryChargingPorts, IsBatteryLowPorts  # noqa: E402
from agv_mission.behaviors.ports.tasks import ChargeTask, DockTask, UndockTask  # noqa: E402

IsBatteryLow.Config = IsBatteryLowPorts  # type: ignore[attr-defined]
IsBatteryCharging.Config = IsBatteryChargingPorts  # type: ignore[attr-defined]
Dock.Config = DockTask  # type: ignore[attr-defined]
Undock.Config = UndockTask  # type: ignore[attr-defined]
Charge.Config = ChargeTask  # type: ignore[attr-defined]
