"""Keyboard teleoperation of the simulated robot, in real time, with a room recorder.

The ``agv-mission teleop`` session: the seed's ``turtlebot3_teleop_key`` /
``teleop_twist_keyboard`` plus its ``rosservice call room_service "kitchen"``.

Keys (each press changes the commanded twist by one step, as turtlebot3_teleop_key does;
limits come from the robot description)::

    w / i / Up      faster forward (linear velocity + step)
    x / , / Down    faster backward (linear velocity - step)
    a / j / Left    turn left faster (angular velocity + step)
    d / l / Right   turn right faster (angular velocity - step)
    s / k / space   stop
    r               record the current estimated pose under a label typed at a prompt
    h / ?           help
    q / Ctrl-C      quit (Ctrl-D too)

The simulation advances one 0.1 s control step per ``0.1 / time_scale`` wall seconds,
reads encoders and lidar, updates odometry and the mission's localiser, and accelerates
towards the commanded twist within the robot's limits. The live line shows the estimated
pose, the measured twist and the room the estimate lies in. While the label prompt is
open the simulation pauses; the pose recorded is the one when ``r`` was pressed.

On a terminal, stdin is put into raw mode (termios) and read without blocking (select);
the terminal is restored on every way out: ``q``, Ctrl-C, an exception, SIGTERM, SIGHUP.
When stdin is not a terminal (a pipe or a file), the same bytes are read as keys, a label
is the rest of a line, and end of input quits.
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from agv_mission.atomic import atomic_write_text
from agv_mission.geometry import Pose2D
from agv_mission.maps.recorder import (
    LocationRecorder,
    load_entries,
)
from agv_mission.maps.rooms import room_at
from agv_mission.missions.loader import LoadedMission, load_mission
from agv_mission.missions.stack import CONTROL_PERIOD, RobotStack
from agv_mission.teleop.terminal import (
    HELP,
    KeyInput,
    Screen,
    TeleopKeys,
    Terminated,
    read_label,
    split_keys,
    termination_signals,
)

DEFAULT_WORLD = "small_house"


# --------------------------------------------------------------------------- mission


def load_teleop_mission(
    mission: str | os.PathLike[str] | None = None,
    world: str | None = None,
    robot: str | None = None,
    overrides: list[str] | None = None,
    seed: int | None = None,
) -> LoadedMission:
    """The mission to drive in: a mission file's world, robot, start and stack, or by
    default the built-in ``small_house`` (``world``/``robot`` override either). Raises
    :class:`~agv_mission.missions.errors.MissionError` on invalid input."""
    sets = list(overrides or [])
    if mission is None:
        doc: dict[str, Any] = {"name": "teleop", "world": world or DEFAULT_WORLD}
        if robot is not None:
            doc["robot"] = robot
        text = yaml.safe_dump(doc, sort_keys=False)
        return load_mission(Path("teleop.yaml"), sets, seed, text=text, tasks_required=False)
    if robot is not None:
        sets.insert(0, f"robot={json.dumps(robot)}")
    if world is not None:
        sets.insert(0, f"world={json.dumps(world)}")
    return load_mission(mission, sets, seed, tasks_required=False)


# --------------------------------------------------------------------------- the robot


class TeleopRobot:
    """The mission's robot and localiser (see :class:`RobotStack`), one step at a time."""

    def __init__(self, loaded: LoadedMission) -> None:
        self.loaded = loaded
        self.stack = RobotStack(loaded)
        self.sim, self.limits = self.stack.sim, self.stack.limits
        self.rows: list[tuple[float, ...]] = []
        self.contact = False
        self._sense()

    @property
    def time(self) -> float:
        return self.sim.time

    @property
    def velocity(self) -> tuple[float, float]:
        """The commanded (smoothed) twist being driven."""
        return self.stack.smoother.v, self.stack.smoother.w

    def room(self) -> str | None:
        """The room the estimated pose lies in."""
        return room_at(self.loaded.rooms, self.estimate.x, self.estimate.y)

    def _sense(self) -> None:
        sensing = self.stack.sense()
        self.truth = sensing.truth
        self.estimate: Pose2D = self.stack.localizer.update(
            sensing.odom, sensing.scan, sensing.truth, sensing.time
        )
        self.contact = self.sim.contacts() > 0

    def step(self, v: float, w: float) -> None:
        """Drive towards the twist (v, w) for one control period, then sense."""
        t, e, now = self.truth, self.estimate, self.sim.time
        v, w = self.stack.drive(v, w)
        self.rows.append((now, t.x, t.y, t.yaw, e.x, e.y, e.yaw, v, w))
        self.stack.advance()
        self._sense()

    def trajectory(self) -> np.ndarray:
        return np.asarray(self.rows, dtype=float).reshape(-1, 9)


def status_line(robot: TeleopRobot, keys: TeleopKeys) -> str:
    """The live line, most important first (an 80-column terminal cuts the end):
    room, estimated pose, driven twist, contact flag, commanded twist, sim time."""
    e = robot.estimate
    v, w = robot.velocity
    contact = " CONTACT" if robot.contact else ""
    return (
        f"room={robot.room() or '-'} x={_f(e.x)} y={_f(e.y)} yaw={_f(e.yaw)} "
        f"v={_f(v)} w={_f(w)}{contact} cmd={_f(keys.v)}/{_f(keys.w)} t={robot.time:.1f}"
    )


def _f(value: float) -> str:
    return f"{round(value, 3) + 0.0:+.3f}"  # no "-0.000"


# --------------------------------------------------------------------------- the session


@dataclass
class TeleopResult:
    """How a session ended and what it left."""

    reason: str  # quit | interrupted | end_of_input | terminated | time_limit
    sim_time: float
    wall_time: float
    recorded: list[str] = field(default_factory=list)  # labels recorded in this session
    trajectory: np.ndarray = field(default_factory=lambda: np.zeros((0, 9)))
    signum: int | None = None

    @property
    def exit_code(self) -> int:
        return 128 + self.signum if self.signum else 0


def run_teleop(
    loaded: LoadedMission,
    recorders: LocationRecorder | Sequence[LocationRecorder],
    *,
    time_scale: float = 1.0,
    stdin_fd: int | None = None,
    out: TextIO | None = None,
    wall_limit: float | None = None,
) -> TeleopResult:
    """Drive ``loaded``'s robot from the keyboard until quit; record into ``recorders``
    (every pose into each; the first is the one shown, see :func:`open_recorders`).

    ``time_scale``: simulated seconds per wall second. ``wall_limit``: end the session
    after that many wall seconds (for scripts). Never leaves the terminal in raw mode.
    """
    if time_scale <= 0:
        raise ValueError("time_scale must be positive")
    if isinstance(recorders, LocationRecorder):
        recorders = [recorders]
    fd = sys.stdin.fileno() if stdin_fd is None else stdin_fd
    screen = Screen(out if out is not None else sys.stdout)
    robot = TeleopRobot(loaded)
    reason, signum = "quit", None
    wall_start = time.monotonic()

    screen.message(
        f"{HELP}\n{loaded.robot.name} in {loaded.world.name}, localization "
        f"{loaded.mission.stack.localization.type}, recorder file "
        + ", ".join(str(r.path) for r in recorders)
    )
    with termination_signals(), KeyInput(fd) as term:
        session = _Session(term, screen, robot, list(recorders))
        try:
            reason = session.loop(time_scale, wall_limit)
        except KeyboardInterrupt:
            reason = "interrupted"
        except Terminated as exc:
            reason, signum = "terminated", exc.signum
        finally:
            robot.sim.set_command(0.0, 0.0)
            term.restore()
            screen.close()
            for recorder in recorders:
                if len(recorder) and not recorder.path.exists():
                    recorder.save()  # appended-to entries, nothing new recorded
    return TeleopResult(
        reason=reason,
        sim_time=round(robot.time, 6),
        wall_time=round(time.monotonic() - wall_start, 3),
        recorded=session.recorded,
        trajectory=robot.trajectory(),
        signum=signum,
    )


class _Session:
    """The real-time loop: keys in, one control step per tick, the live line out."""

    def __init__(
        self,
        term: KeyInput,
        screen: Screen,
        robot: TeleopRobot,
        recorders: list[LocationRecorder],
    ) -> None:
        self.term, self.screen, self.robot, self.recorders = term, screen, robot, recorders
        self.keys = TeleopKeys.for_limits(robot.limits)
        self.recorded: list[str] = []
        self.buf = bytearray()
        self.paused = False

    def loop(self, time_scale: float, wall_limit: float | None) -> str:
        period = CONTROL_PERIOD / time_scale
        start = next_tick = time.monotonic()
        self._show()
        while True:
            data = self.term.read(next_tick - time.monotonic())
            if data:
                self.buf += data
            if self._handle_keys():
                return "quit"
            if data is None:
                return "end_of_input"
            now = time.monotonic()
            if self.paused:  # the sim stood still during the label prompt: no catch-up
                self.paused, next_tick = False, now
            if now >= next_tick:
                self.robot.step(self.keys.v, self.keys.w)
                self._show()
                next_tick += period
                if now - next_tick > period:  # fell behind: drop the backlog
                    next_tick = now
            if wall_limit is not None and now - start >= wall_limit:
                return "time_limit"

    def _show(self) -> None:
        self.screen.status(status_line(self.robot, self.keys), self.robot.time)

    def _handle_keys(self) -> bool:
        """Act on every whole key in the buffer; True when one of them quits."""
        while True:
            for key in split_keys(self.buf):
                action = self.keys.press(key)
                if action == "quit":
                    return True
                if action == "help":
                    self.screen.message(HELP)
                elif action == "record":
                    pose = self.robot.estimate
                    self._record(read_label(self.term, self.screen, self.buf), pose)
                    self.paused = True
                    break  # the buffer changed under the iterator: start over
            else:
                return False

    def _record(self, label: str | None, pose: Pose2D) -> None:
        screen = self.screen
        if not label:
            screen.message("nothing recorded (no label)")
            return
        written, failed = [], []
        for recorder in self.recorders:
            try:
                recorder.record(label, pose)
                n = len(recorder)
                written.append(f"{recorder.path} ({n} {'entry' if n == 1 else 'entries'})")
            except (OSError, ValueError) as exc:
                failed.append(f"NOT recorded {label!r} in {recorder.path}: {exc}")
        if written:
            self.recorded.append(label)
        text = "\n".join(failed)
        if not written:
            screen.message(text)
            return
        text = (
            f"recorded {label!r} at x={pose.x:.3f} y={pose.y:.3f} yaw={pose.yaw:.3f} "
            f"in {', '.join(written)}" + (f"\n{text}" if text else "")
        )
        rooms = self.robot.loaded.rooms
        room = rooms.get(label)
        if room is not None and not room.contains(pose.x, pose.y):
            here = room_at(rooms, pose.x, pose.y)
            text += f"\nwarning: the robot is not in {label!r} (it is in {here or 'no room'})"
        screen.message(text)


# --------------------------------------------------------------------------- outputs


def check_recorder_file(path: Path) -> None:
    """Raise :class:`~agv_mission.maps.recorder.RecorderFileError` unless ``path`` is a
    readable recorder file (before anything is created)."""
    load_entries(path)


def write_teleop_outputs(run_dir: Path, loaded: LoadedMission, result: TeleopResult) -> None:
    """``mission.yaml`` (without tasks) and ``trajectory.csv`` of the session."""
    from agv_mission.missions.outputs import write_trajectory

    doc = loaded.resolved()
    doc.pop("tasks", None)
    doc["teleop"] = {"reason": result.reason, "sim_time": result.sim_time}
    atomic_write_text(
        run_dir / "mission.yaml", yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    )
    write_trajectory(run_dir / "trajectory.csv", result.trajectory)
