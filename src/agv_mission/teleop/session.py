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
from typing import TextIO

import numpy as np
import yaml

from agv_mission.atomic import atomic_write_text
from agv_mission.geometry import Pose2D
from agv_mission.maps.recorder import (
    LocationRecorder,
    load_entries,
    open_recorders,
)
from agv_mission.maps.rooms import room_at
from agv_mission.missions.load.loader import load_mission, remote_controlled
from agv_mission.missions.load.overrides import Override
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.load.schema import MAX_SIM_SECONDS
from agv_mission.missions.report.outputs import make_run_dir, write_trajectory
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.stack import CONTROL_PERIOD
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
    :class:`~agv_mission.missions.load.errors.MissionError` on invalid input."""
    sets: list[str | Override] = []
    for option, value in (("--world", world), ("--robot", robot)):
        if value is not None:  # errors in them name the option, not a file line
            key = option.removeprefix("--")
            sets.append(Override(f"{key}={json.dumps(value)}", option, f"{option} {value}"))
    sets += overrides or []
    if mission is None:
        text = yaml.safe_dump({"name": "teleop", "world": DEFAULT_WORLD}, sort_keys=False)
        return load_mission(Path("teleop.yaml"), sets, seed, text=text, tasks_required=False)
    return load_mission(mission, sets, seed, tasks_required=False)


# --------------------------------------------------------------------------- the mission


TELEOP_TIME_LIMIT = MAX_SIM_SECONDS  # a session ends when its driver says so (a day at most)


def teleop_mission(loaded: LoadedMission) -> LoadedMission:
    """``loaded``'s setup with one ``teleop`` task: the same task the service runs, so the
    terminal is one more client of it, not a second implementation."""
    return remote_controlled(loaded, TELEOP_TIME_LIMIT)


def status_line(run: MissionRun, keys: TeleopKeys) -> str:
    """The live line, most important first (an 80-column terminal cuts the end):
    room, estimated pose, driven twist, contact flag, commanded twist, sim time."""
    e = run.handle.state.estimate
    v, w = run.handle.state.velocity
    contact = " CONTACT" if run.sim.contacts() > 0 else ""
    room = room_at(run.loaded.rooms, e.x, e.y)
    return (
        f"room={room or '-'} x={_f(e.x)} y={_f(e.y)} yaw={_f(e.yaw)} "
        f"v={_f(v)} w={_f(w)}{contact} cmd={_f(keys.v)}/{_f(keys.w)} t={run.sim.time:.1f}"
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
    battery: np.ndarray | None = None  # the level at each step; None: not modelled

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

    The run is a mission with one ``teleop`` task (:func:`teleop_mission`) run by the
    mission runner; this session is its :class:`~agv_mission.missions.run.observe.RunControl`:
    keys set the remote command, and each control step waits for its wall-clock tick.
    ``time_scale``: simulated seconds per wall second. ``wall_limit``: end the session
    after that many wall seconds (for scripts). Never leaves the terminal in raw mode.
    """
    if time_scale <= 0:
        raise ValueError("time_scale must be positive")
    if isinstance(recorders, LocationRecorder):
        recorders = [recorders]
    fd = sys.stdin.fileno() if stdin_fd is None else stdin_fd
    screen = Screen(out if out is not None else sys.stdout)
    mission = teleop_mission(loaded)
    wall_start = time.monotonic()

    screen.message(
        f"{HELP}\n{loaded.robot.name} in {loaded.world.name}, localization "
        f"{loaded.mission.stack.localization.type}, recorder file "
        + ", ".join(str(r.path) for r in recorders)
    )
    record = None
    with termination_signals(), KeyInput(fd) as term:
        control = KeyboardControl(term, screen, list(recorders), time_scale, wall_limit)
        try:
            record = run_mission(mission, None, control=control)
            if record.status == "aborted" and control.reason == "quit" and control.quit_at is None:
                control.reason = "interrupted"  # Ctrl-C as a signal, not as a key
        except Terminated as exc:
            control.reason, control.signum = "terminated", exc.signum
            if control.run is not None:
                control.run.cancel("terminated")
                record = control.run.record()
        finally:
            if control.run is not None:
                control.run.sim.set_command(0.0, 0.0)
            term.restore()
            screen.close()
            for recorder in recorders:
                if len(recorder) and not recorder.path.exists():
                    recorder.save()  # appended-to entries, nothing new recorded
    return TeleopResult(
        reason=control.reason,
        sim_time=round(record.sim_time if record is not None else 0.0, 6),
        wall_time=round(time.monotonic() - wall_start, 3),
        recorded=control.recorded,
        trajectory=record.trajectory if record is not None else np.zeros((0, 9)),
        signum=control.signum,
        battery=record.battery if record is not None else None,
    )


class KeyboardControl:
    """The real-time loop as a run control: keys in, one control step per tick, the live
    line out. Sets the teleop task's remote command; records through the run's handle."""

    def __init__(
        self,
        term: KeyInput,
        screen: Screen,
        recorders: list[LocationRecorder],
        time_scale: float,
        wall_limit: float | None,
    ) -> None:
        self.term, self.screen, self.recorders = term, screen, recorders
        self.period = CONTROL_PERIOD / time_scale
        self.wall_limit = wall_limit
        self.keys: TeleopKeys | None = None
        self.recorded: list[str] = []
        self.buf = bytearray()
        self.run: MissionRun | None = None
        self.reason = "quit"
        self.quit_at: float | None = None
        self.signum: int | None = None
        self.start = self.next_tick = time.monotonic()

    def before_step(self, run: MissionRun) -> None:
        if self.run is None:  # the first step: this session's recorders, keys, clock
            self.run = run
            run.handle.recorders = self.recorders
            self.keys = TeleopKeys.for_limits(run.lead.limits)
            self.start = self.next_tick = time.monotonic()
        else:
            self.next_tick += self.period
        keys = self.keys
        assert keys is not None
        self._show()
        while True:
            now = time.monotonic()
            if self.wall_limit is not None and now - self.start >= self.wall_limit:
                return self._end("time_limit")
            data = self.term.read(max(self.next_tick - now, 0.0))
            if data:
                self.buf += data
            if self._handle_keys():
                self.quit_at = time.monotonic()
                return self._end("quit")
            if data is None:
                return self._end("end_of_input")
            now = time.monotonic()
            if now >= self.next_tick:
                if now - self.next_tick > self.period:  # fell behind: drop the backlog
                    self.next_tick = now
                break
        run.handle.remote_command = (keys.v, keys.w)

    def _end(self, reason: str) -> None:
        self.reason = reason
        assert self.run is not None
        self.run.cancel(reason)

    def _show(self) -> None:
        assert self.run is not None and self.keys is not None
        self.screen.status(status_line(self.run, self.keys), self.run.sim.time)

    def _handle_keys(self) -> bool:
        """Act on every whole key in the buffer; True when one of them quits."""
        assert self.keys is not None and self.run is not None
        while True:
            for key in split_keys(self.buf):
                action = self.keys.press(key)
                if action == "quit":
                    return True
                if action == "help":
                    self.screen.message(HELP)
                elif action == "record":
                    pose = self.run.handle.state.estimate
                    self._record(read_label(self.term, self.screen, self.buf), pose)
                    self.next_tick = time.monotonic()  # the sim stood still: no catch-up
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
            assert self.run is not None
            handle = self.run.handle
            handle.recorded[label] = pose
            handle.log_recorded(label, pose, source="keyboard")
        text = "\n".join(failed)
        if not written:
            screen.message(text)
            return
        text = (
            f"recorded {label!r} at x={pose.x:.3f} y={pose.y:.3f} yaw={pose.yaw:.3f} "
            f"in {', '.join(written)}" + (f"\n{text}" if text else "")
        )
        assert self.run is not None
        rooms = self.run.loaded.rooms
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


def open_session(
    loaded: LoadedMission,
    output: Path | None,
    recorder: Path | None,
    append: Path | None,
) -> tuple[Path | None, list[LocationRecorder]]:
    """The session's run directory (none when recording straight into ``recorder``) and
    its recorders. Raises :class:`~agv_mission.maps.recorder.RecorderFileError` for a
    recorder file that cannot be read or would be replaced, before anything is created."""
    if recorder is not None:
        return None, open_recorders(None, loaded.recorder, recorder, append)
    if append is not None:
        check_recorder_file(append)
    root = output if output is not None else Path(loaded.mission.output)
    name = loaded.name if loaded.name == "teleop" else f"{loaded.name}-teleop"
    run_dir = make_run_dir(root, name)
    return run_dir, open_recorders(run_dir, loaded.recorder, None, append)


def session_report(
    result: TeleopResult, recorders: list[LocationRecorder], run_dir: Path | None
) -> list[str]:
    """What the session left behind, a line each: how it ended, files and run directory."""
    lines = [f"teleop ended ({result.reason}) after {result.sim_time:.1f} sim s"]
    saved = [r for r in recorders if len(r) and r.path.exists()]
    for rec in saved:
        n = len(rec)
        lines.append(
            f"recorder file: {rec.path} ({n} entr{'y' if n == 1 else 'ies'}: {', '.join(rec.labels)})"
        )
    if not saved:
        lines.append("nothing recorded; no recorder file written")
    if run_dir is not None:
        lines.append(f"run directory: {run_dir}")
    return lines


def write_teleop_outputs(run_dir: Path, loaded: LoadedMission, result: TeleopResult) -> None:
    """``mission.yaml`` (without tasks) and ``trajectory.csv`` of the session."""
    doc = loaded.resolved()
    for key in ("tasks", "tree", "trees", "blackboard"):
        doc.pop(key, None)
    doc["teleop"] = {"reason": result.reason, "sim_time": result.sim_time}
    atomic_write_text(
        run_dir / "mission.yaml", yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
    )
    write_trajectory(run_dir / "trajectory.csv", result.trajectory, battery=result.battery)
