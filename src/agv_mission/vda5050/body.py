"""The vehicles' bodies: what a VDA 5050 vehicle needs of a robot, behind a narrow interface.

:class:`VehicleBody` is all the protocol side uses (pose, velocity, a navigation goal with
tolerances and a speed cap, cancel, pause, set the pose, charge). :class:`VehicleWorld` is
a mission's one world with every robot under remote command: one
:class:`~agv_mission.missions.run.runner.MissionRun` holding every robot (its lidar sees the
others, their contacts count), each robot running its whole stack (localiser, global
planner, controller on MuJoCo) with one open-ended ``teleop`` task, the same task the
service uses for ``POST .../goal``. The world is the run's
:class:`~agv_mission.missions.run.observe.RunControl`: it paces simulated time to the wall clock
times ``time_scale`` and, between two control steps, lets each robot's
:class:`SimulatedBody` hand its robot the goals its vehicle asked for and read back its
state.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Literal, Protocol

from agv_mission.geometry import Pose2D
from agv_mission.missions.load.loader import remote_controlled
from agv_mission.missions.load.resolved import LoadedMission, RobotSetup
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.robot_run import RobotRun
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.stack import CONTROL_PERIOD

NavState = Literal["idle", "running", "succeeded", "failed"]

#: m from a dock's pose within which ``startCharging`` connects to its charger: a node at
#: the dock's pose is reached within 0.05 m (the navigator's default goal tolerance);
#: the margin allows an ``allowedDeviationXY`` a master may give the charging node
DOCK_REACH = 0.25


@dataclass(frozen=True)
class BodySnapshot:
    """The body as the vehicle reports it, taken between two control steps."""

    time: float  # simulated seconds
    pose: Pose2D  # the localiser's estimate, map frame
    v: float  # m/s
    w: float  # rad/s
    nav: NavState  # of the last goal
    reason: str | None  # why it failed
    goal_id: int  # which navigate_to the state belongs to
    paused: bool
    fault: str | None = None  # why the simulation stopped, once it has
    battery: float | None = None  # state of charge 0..1 (None: the robot models no battery)
    voltage: float | None = None  # the battery's nominal V, when the robot file gives it
    charging: bool = False
    dock: str | None = None  # the dock the robot stands on
    charge_id: int = 0  # the last start/stop charging request the body has handled
    charge_error: str | None = None  # why that request could not be done


class VehicleBody(Protocol):
    """A robot a VDA 5050 vehicle can drive: the only calls the protocol side makes."""

    map_id: str
    robot_name: str
    extent: tuple[float, float, float, float]  # the map's (xmin, xmax, ymin, ymax), metres

    def snapshot(self) -> BodySnapshot: ...

    def navigate_to(
        self,
        pose: Pose2D,
        xy_tolerance: float | None,
        yaw_tolerance: float | None,
        max_speed: float | None,
    ) -> int:
        """Start driving to ``pose``; returns the goal's id (as in snapshots)."""
        ...

    def cancel(self) -> None: ...

    def pause(self) -> None: ...

    def resume(self) -> None: ...

    def set_pose(self, pose: Pose2D) -> None:
        """Reset the localiser to ``pose`` (the standard's initPosition)."""
        ...

    def charge(self, on: bool) -> int:
        """Start (dock onto the dock the robot stands at) or stop charging; returns the
        request's id (``charge_id`` of the snapshots that answer it)."""
        ...


class VehicleWorld:
    """A mission's world with every robot under remote command, run on a thread of its own
    at wall-clock pace (times ``time_scale``); ``bodies`` by robot name."""

    def __init__(self, loaded: LoadedMission, time_scale: float = 1.0) -> None:
        if time_scale <= 0:
            raise ValueError("time_scale must be positive")
        self.loaded = remote_controlled(loaded)
        self.period = CONTROL_PERIOD / time_scale
        self.bodies = {
            setup.name: SimulatedBody(self.loaded, setup) for setup in self.loaded.robots
        }
        self.run: MissionRun | None = None  # once the run has been set up
        self.ready = threading.Event()
        self.record: RunRecord | None = None
        self.error: str | None = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_tick = 0.0

    def start(self) -> None:
        self._thread = threading.Thread(
            target=self._run, name=f"world-{self.loaded.world.name}", daemon=True
        )
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        fault = "the simulation stopped"
        try:
            self.record = run_mission(self.loaded, None, control=self)
            fault = f"the simulation ended ({self.record.status}): {self.record.reason}"
            if self.record.status == "error":
                self.error = self.record.reason
        finally:
            self.ready.set()
            for body in self.bodies.values():
                body.end(fault)

    def before_step(self, run: MissionRun) -> None:
        """Every body sees its robot's step, then the wall clock catches up, then every
        body's queued commands go into the step that follows."""
        if self._stop.is_set():
            run.cancel("vehicle stopped")
            return
        if not self.ready.is_set():
            self.run = run
            self.ready.set()
            self._next_tick = time.monotonic()
        for name, body in self.bodies.items():
            body.observe(run.by_name[name])
        self._next_tick += self.period
        delay = self._next_tick - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)
        elif delay < -1.0:  # fell behind by more than a second: do not race to catch up
            self._next_tick = time.monotonic()
        if self._stop.is_set():
            run.cancel("vehicle stopped")
            return
        for name, body in self.bodies.items():
            body.apply(run.by_name[name])


class SimulatedBody:
    """One robot of a :class:`VehicleWorld`: its vehicle's calls become commands its robot
    takes between two control steps, and its state comes back as snapshots."""

    def __init__(self, loaded: LoadedMission, setup: RobotSetup) -> None:
        self.loaded = loaded
        self.map_id = loaded.world.name
        self.extent = loaded.world.map.extent
        self.robot_name = setup.name
        self.robot = setup.robot
        self.on_change: Callable[[], None] | None = None
        self._localization = setup.stack.localization.type
        self._commands: queue.SimpleQueue[Callable[[RobotRun], None]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._snap = BodySnapshot(0.0, setup.start, 0.0, 0.0, "idle", None, 0, False)
        self._goal: tuple[Pose2D, tuple[float | None, float | None], float | None] | None = None
        self._goal_counter = 0  # goals asked for
        self._goal_id = 0  # the goal the run drives to (snapshots report its state)
        self._nav: NavState = "idle"
        self._reason: str | None = None
        self._paused = False
        self._events_seen = 0
        self._charge_counter = 0
        self._charge_id = 0
        self._charge_error: str | None = None

    # ---------------------------------------------------------------- the interface

    def snapshot(self) -> BodySnapshot:
        with self._lock:
            return self._snap

    def navigate_to(
        self,
        pose: Pose2D,
        xy_tolerance: float | None = None,
        yaw_tolerance: float | None = None,
        max_speed: float | None = None,
    ) -> int:
        with self._lock:
            self._goal_counter += 1
            goal_id = self._goal_counter
        self._commands.put(
            lambda r: self._set_goal(r, goal_id, pose, (xy_tolerance, yaw_tolerance), max_speed)
        )
        return goal_id

    def cancel(self) -> None:
        self._commands.put(self._cancel)

    def pause(self) -> None:
        self._commands.put(lambda r: self._set_paused(r, True))

    def resume(self) -> None:
        self._commands.put(lambda r: self._set_paused(r, False))

    def set_pose(self, pose: Pose2D) -> None:
        self._commands.put(lambda r: self._reset_pose(r, pose))

    def charge(self, on: bool) -> int:
        with self._lock:
            self._charge_counter += 1
            request = self._charge_counter
        self._commands.put(lambda r: self._set_charging(r, request, on))
        return request

    # ---------------------------------------------------------------- on the world's thread

    def end(self, fault: str) -> None:
        """The world's run is over: the vehicle reports why and stands still."""
        with self._lock:
            self._snap = replace(self._snap, fault=fault, v=0.0, w=0.0)
        if self.on_change is not None:
            self.on_change()

    def observe(self, robot: RobotRun) -> None:
        """See how the goal went and publish a snapshot of the step just made."""
        self._watch_goal(robot)
        self._watch_dock(robot)
        handle, smoother = robot.handle, robot.stack.smoother
        goal, nav, paused = self._goal, self._nav, self._paused
        if nav == "running" and goal is not None and not paused and handle.remote_goal is None:
            handle.remote_goal = goal[0]  # the teleop task's first tick had cleared it
        v, w = smoother.v, smoother.w  # the command of the step just made (state's lags one)
        battery = handle.battery
        snap = BodySnapshot(
            robot.sim.time,
            handle.state.estimate,
            v,
            w,
            self._nav,
            self._reason,
            self._goal_id,
            self._paused,
            battery=None if battery is None else battery.level,
            voltage=None if battery is None else battery.spec.voltage,
            charging=battery is not None and battery.charging,
            dock=None if handle.docked is None else handle.docked.name,
            charge_id=self._charge_id,
            charge_error=self._charge_error,
        )
        with self._lock:
            changed = _phase(snap) != _phase(self._snap)
            self._snap = snap
        if changed and self.on_change is not None:
            self.on_change()

    def apply(self, robot: RobotRun) -> None:
        """The commands that came since the last step, in the order they came."""
        while True:
            try:
                self._commands.get_nowait()(robot)
            except queue.Empty:
                break

    def _set_goal(
        self,
        robot: RobotRun,
        goal_id: int,
        pose: Pose2D,
        tolerance: tuple[float | None, float | None],
        max_speed: float | None,
    ) -> None:
        handle = robot.handle
        handle.navigator.cancel()
        self._goal = (pose, tolerance, max_speed)
        self._goal_id, self._nav, self._reason = goal_id, "running", None
        self._events_seen = len(handle.events)
        handle.remote_goal_tolerance = tolerance
        handle.remote_speed_limit = max_speed
        handle.remote_goal = None if self._paused else pose

    def _cancel(self, robot: RobotRun) -> None:
        handle = robot.handle
        handle.remote_goal = None
        handle.navigator.cancel()
        if self._nav == "running":
            self._nav, self._reason = "failed", "cancelled"
        self._goal = None

    def _set_paused(self, robot: RobotRun, paused: bool) -> None:
        handle = robot.handle
        self._paused = paused
        if paused:
            handle.remote_goal = None
            handle.navigator.cancel()  # resumed with a fresh plan from where it stands
        elif self._goal is not None and self._nav == "running":
            handle.remote_goal = self._goal[0]

    def _reset_pose(self, robot: RobotRun, pose: Pose2D) -> None:
        """A localiser's belief is reset (a real AGV's initPosition); with ``ground_truth``
        localisation the belief is the truth, so the simulated robot is placed there."""
        robot.handle.navigator.cancel()
        if self._localization == "ground_truth":
            robot.sim.teleport(pose)
        robot.localizer.reset(pose, robot.stack.odom)
        robot.handle.state.estimate = pose

    def _set_charging(self, robot: RobotRun, request: int, on: bool) -> None:
        """Dock onto the nearest dock within :data:`DOCK_REACH` and charge, or stop. A real
        AGV is sent to its charging station node and then told ``startCharging``; it
        connects to the charger where it stands, it does not drive anywhere for it."""
        handle, battery = robot.handle, robot.handle.battery
        self._charge_id, self._charge_error = request, None
        if not on:
            if battery is not None:
                battery.charging = False
            handle.docked = None
            return
        if battery is None:
            self._charge_error = f"robot {self.robot.name!r} models no battery to charge"
            return
        here = handle.state.estimate
        near = sorted(
            (math.hypot(d.pose.x - here.x, d.pose.y - here.y), name)
            for name, d in handle.docks.items()
        )
        if not near:
            self._charge_error = f"world {self.map_id!r} has no dock"
            return
        distance, name = near[0]
        if distance > DOCK_REACH:
            self._charge_error = (
                f"not at a dock: the nearest, {name!r} at ({handle.docks[name].pose.x:g}, "
                f"{handle.docks[name].pose.y:g}), is {distance:.2f} m away "
                f"(a vehicle charges within {DOCK_REACH:g} m of a dock's pose)"
            )
            return
        handle.docked = handle.docks[name]
        battery.charging = True
        handle.log("charging", dock=name, level=round(battery.level, 4))

    def _watch_dock(self, robot: RobotRun) -> None:
        """Charging ends when the robot drives off its dock (the contacts part)."""
        handle, battery = robot.handle, robot.handle.battery
        dock = handle.docked
        if battery is None or dock is None or not battery.charging:
            return
        est = handle.state.estimate
        if math.hypot(est.x - dock.pose.x, est.y - dock.pose.y) > DOCK_REACH:
            battery.charging = False
            handle.docked = None
            handle.log("undocked", dock=dock.name)

    def _watch_goal(self, robot: RobotRun) -> None:
        events = robot.handle.events
        while self._events_seen < len(events):
            event = events[self._events_seen]
            self._events_seen += 1
            if self._nav != "running" or event.get("goal") != "remote goal":
                continue
            if event["event"] == "goal_reached":
                self._nav, self._goal = "succeeded", None
            elif event["event"] == "goal_failed":
                self._nav, self._reason, self._goal = "failed", str(event.get("reason")), None


def yaw_or_free(
    theta: float | None, here: Pose2D, x: float, y: float
) -> tuple[Pose2D, float | None]:
    """A goal pose for a node: its ``theta``, or (none given) the heading from ``here`` with
    any final orientation accepted."""
    if theta is not None:
        return Pose2D(x, y, theta), None
    heading = math.atan2(y - here.y, x - here.x) if (x, y) != (here.x, here.y) else here.yaw
    return Pose2D(x, y, heading), math.pi


def _phase(snap: BodySnapshot) -> tuple[object, ...]:
    """What a change of wakes the vehicle: the goal's state, pause, moving or not."""
    moving = abs(snap.v) > 1e-3 or abs(snap.w) > 1e-3
    return (snap.nav, snap.goal_id, snap.paused, moving, snap.charging, snap.charge_id)
