"""The vehicle's body: what a VDA 5050 vehicle needs of a robot, behind a narrow interface.

:class:`VehicleBody` is all the protocol side uses (pose, velocity, a navigation goal with
tolerances and a speed cap, cancel, pause, set the pose), so a fleet world serving many
robots can stand in for :class:`SimulatedBody` later. :class:`SimulatedBody` is one robot
of a mission running its whole stack (localiser, global planner, controller on MuJoCo)
through the mission runner with one ``teleop`` task, the same task the service uses for
``POST .../goal``: this body is the run's :class:`~agv_mission.missions.observe.RunControl`,
pacing simulated time to the wall clock times ``time_scale`` and handing the task its goals.
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
from agv_mission.missions.loader import LoadedMission, remote_controlled
from agv_mission.missions.runner import MissionRun, RunRecord, run_mission
from agv_mission.missions.stack import CONTROL_PERIOD

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


class SimulatedBody:
    """One simulated robot running its mission stack on a thread of its own."""

    def __init__(
        self,
        loaded: LoadedMission,
        time_scale: float = 1.0,
        on_change: Callable[[], None] | None = None,
    ) -> None:
        if time_scale <= 0:
            raise ValueError("time_scale must be positive")
        self.loaded = loaded
        self.map_id = loaded.world.name
        self.robot_name = loaded.robot.name
        self.period = CONTROL_PERIOD / time_scale
        self.on_change = on_change
        self._commands: queue.SimpleQueue[Callable[[MissionRun], None]] = queue.SimpleQueue()
        self._lock = threading.Lock()
        self._snap = BodySnapshot(0.0, loaded.start, 0.0, 0.0, "idle", None, 0, False)
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
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._next_tick = 0.0
        self.ready = threading.Event()
        self.record: RunRecord | None = None
        self.error: str | None = None

    # ---------------------------------------------------------------- life

    def start(self) -> None:
        self._thread = threading.Thread(
            target=self._run, name=f"body-{self.robot_name}", daemon=True
        )
        self._thread.start()

    def stop(self, timeout: float = 10.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)

    def _run(self) -> None:
        fault = "the simulation stopped"
        try:
            self.record = run_mission(remote_controlled(self.loaded), None, control=self)
            fault = f"the simulation ended ({self.record.status}): {self.record.reason}"
            if self.record.status == "error":
                self.error = self.record.reason
        finally:
            with self._lock:
                self._snap = replace(self._snap, fault=fault, v=0.0, w=0.0)
            self.ready.set()
            if self.on_change is not None:
                self.on_change()

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
            lambda run: self._set_goal(run, goal_id, pose, (xy_tolerance, yaw_tolerance), max_speed)
        )
        return goal_id

    def cancel(self) -> None:
        self._commands.put(self._cancel)

    def pause(self) -> None:
        self._commands.put(lambda run: self._set_paused(run, True))

    def resume(self) -> None:
        self._commands.put(lambda run: self._set_paused(run, False))

    def set_pose(self, pose: Pose2D) -> None:
        self._commands.put(lambda run: self._reset_pose(run, pose))

    def charge(self, on: bool) -> int:
        with self._lock:
            self._charge_counter += 1
            request = self._charge_counter
        self._commands.put(lambda run: self._set_charging(run, request, on))
        return request

    # ---------------------------------------------------------------- on the run's thread

    def before_step(self, run: MissionRun) -> None:
        """Apply queued commands, see how the goal went, publish a snapshot, keep pace."""
        if self._stop.is_set():
            run.cancel("vehicle stopped")
            return
        if not self.ready.is_set():
            self.ready.set()
            self._next_tick = time.monotonic()
        self._watch_goal(run)
        self._watch_dock(run)
        handle, smoother = run.handle, run.stack.smoother
        goal, nav, paused = self._goal, self._nav, self._paused
        if nav == "running" and goal is not None and not paused and handle.remote_goal is None:
            handle.remote_goal = goal[0]  # the teleop task's first tick had cleared it
        v, w = smoother.v, smoother.w  # the command of the step just made (state's lags one)
        battery = handle.battery
        snap = BodySnapshot(
            run.sim.time,
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
        self._next_tick += self.period
        delay = self._next_tick - time.monotonic()
        if delay > 0:
            self._stop.wait(delay)
        elif delay < -1.0:  # fell behind by more than a second: do not race to catch up
            self._next_tick = time.monotonic()
        if self._stop.is_set():
            run.cancel("vehicle stopped")
            return
        while True:  # commands that came while waiting go into the step that follows now
            try:
                self._commands.get_nowait()(run)
            except queue.Empty:
                break

    def _set_goal(
        self,
        run: MissionRun,
        goal_id: int,
        pose: Pose2D,
        tolerance: tuple[float | None, float | None],
        max_speed: float | None,
    ) -> None:
        handle = run.handle
        handle.navigator.cancel()
        self._goal = (pose, tolerance, max_speed)
        self._goal_id, self._nav, self._reason = goal_id, "running", None
        self._events_seen = len(handle.events)
        handle.remote_goal_tolerance = tolerance
        handle.remote_speed_limit = max_speed
        handle.remote_goal = None if self._paused else pose

    def _cancel(self, run: MissionRun) -> None:
        handle = run.handle
        handle.remote_goal = None
        handle.navigator.cancel()
        if self._nav == "running":
            self._nav, self._reason = "failed", "cancelled"
        self._goal = None

    def _set_paused(self, run: MissionRun, paused: bool) -> None:
        handle = run.handle
        self._paused = paused
        if paused:
            handle.remote_goal = None
            handle.navigator.cancel()  # resumed with a fresh plan from where it stands
        elif self._goal is not None and self._nav == "running":
            handle.remote_goal = self._goal[0]

    def _reset_pose(self, run: MissionRun, pose: Pose2D) -> None:
        """A localiser's belief is reset (a real AGV's initPosition); with ``ground_truth``
        localisation the belief is the truth, so the simulated robot is placed there."""
        run.handle.navigator.cancel()
        if run.mission.stack.localization.type == "ground_truth":
            run.sim.teleport(pose)
        run.localizer.reset(pose, run.stack.odom)
        run.handle.state.estimate = pose

    def _set_charging(self, run: MissionRun, request: int, on: bool) -> None:
        """Dock onto the nearest dock within :data:`DOCK_REACH` and charge, or stop. A real
        AGV is sent to its charging station node and then told ``startCharging``; it
        connects to the charger where it stands, it does not drive anywhere for it."""
        handle, battery = run.handle, run.handle.battery
        self._charge_id, self._charge_error = request, None
        if not on:
            if battery is not None:
                battery.charging = False
            handle.docked = None
            return
        if battery is None:
            self._charge_error = f"robot {self.robot_name!r} models no battery to charge"
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

    def _watch_dock(self, run: MissionRun) -> None:
        """Charging ends when the robot drives off its dock (the contacts part)."""
        handle, battery = run.handle, run.handle.battery
        dock = handle.docked
        if battery is None or dock is None or not battery.charging:
            return
        est = handle.state.estimate
        if math.hypot(est.x - dock.pose.x, est.y - dock.pose.y) > DOCK_REACH:
            battery.charging = False
            handle.docked = None
            handle.log("undocked", dock=dock.name)

    def _watch_goal(self, run: MissionRun) -> None:
        events = run.handle.events
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
