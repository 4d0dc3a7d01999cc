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

import contextlib
import json
import math
import os
import select
import shutil
import signal
import sys
import termios
import time
import tty
from collections.abc import Iterator, Sequence
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
from agv_mission.planners.base import VelocityLimits

DEFAULT_WORLD = "small_house"
LINEAR_STEPS = 10  # key presses from standstill to full speed
ANGULAR_STEPS = 10

HELP = """\
agv-mission teleop: drive the robot, record rooms
  w/i/Up    faster forward        x/,/Down   faster backward
  a/j/Left  turn left faster      d/l/Right  turn right faster
  s/k/space stop                  r          record pose under a label
  h/?       this help             q/Ctrl-C   quit"""

ACTIONS = {
    "forward": ("w", "i", "UP"),
    "backward": ("x", ",", "DOWN"),
    "left": ("a", "j", "LEFT"),
    "right": ("d", "l", "RIGHT"),
    "stop": ("s", "k", " "),
    "record": ("r",),
    "help": ("h", "?"),
    "quit": ("q", "\x03", "\x04"),  # q, Ctrl-C, Ctrl-D
}
KEY_ACTIONS = {key: action for action, keys in ACTIONS.items() for key in keys}
_ARROWS = {b"A": "UP", b"B": "DOWN", b"C": "RIGHT", b"D": "LEFT"}


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


# --------------------------------------------------------------------------- keys -> twist


@dataclass
class TeleopKeys:
    """turtlebot3_teleop_key's step logic: each key moves the target twist by one step."""

    max_v: float
    max_w: float
    v_step: float
    w_step: float
    v: float = 0.0
    w: float = 0.0

    @classmethod
    def for_limits(cls, limits: VelocityLimits) -> TeleopKeys:
        return cls(
            limits.max_v, limits.max_w, limits.max_v / LINEAR_STEPS, limits.max_w / ANGULAR_STEPS
        )

    def press(self, key: str) -> str | None:
        """Apply ``key``; returns its action name (None for an unknown key)."""
        action = KEY_ACTIONS.get(key)
        if action == "forward":
            self.v = self._clip(self.v + self.v_step, self.max_v)
        elif action == "backward":
            self.v = self._clip(self.v - self.v_step, self.max_v)
        elif action == "left":
            self.w = self._clip(self.w + self.w_step, self.max_w)
        elif action == "right":
            self.w = self._clip(self.w - self.w_step, self.max_w)
        elif action == "stop":
            self.v = self.w = 0.0
        return action

    @staticmethod
    def _clip(value: float, limit: float) -> float:
        value = max(-limit, min(limit, value))
        return 0.0 if abs(value) < 1e-9 else round(value, 9)


def split_keys(buf: bytearray) -> Iterator[str]:
    """Consume ``buf`` key by key: characters, and arrow keys as ``UP`` / ``DOWN`` / ..."""
    while buf:
        if buf[0] == 0x1B:  # Escape: an arrow key's CSI/SS3 sequence, or dropped
            if len(buf) >= 3 and buf[1] in (0x5B, 0x4F):
                j = 2
                while j < len(buf) - 1 and 0x30 <= buf[j] <= 0x3F:
                    j += 1  # parameter bytes
                key = _ARROWS.get(bytes(buf[j : j + 1])) if j == 2 else None
                del buf[: j + 1]
                if key is not None:
                    yield key
            else:
                del buf[:1]
            continue
        n = _utf8_length(buf[0])
        if len(buf) < n:
            return  # wait for the rest of the character
        chunk = bytes(buf[:n])
        del buf[:n]
        yield chunk.decode("utf-8", errors="replace")


def _utf8_length(first: int) -> int:
    if first < 0x80:
        return 1
    if first >> 5 == 0b110:
        return 2
    if first >> 4 == 0b1110:
        return 3
    return 4 if first >> 3 == 0b11110 else 1


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


# --------------------------------------------------------------------------- the terminal


class Terminated(BaseException):
    """SIGTERM or SIGHUP arrived; unwinds the session like Ctrl-C does."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


class KeyInput:
    """stdin as keys: raw mode and non-blocking reads on a terminal, plain bytes otherwise."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.is_tty = os.isatty(fd)
        self._saved: list[Any] | None = None

    def __enter__(self) -> KeyInput:
        if self.is_tty:
            self._saved = termios.tcgetattr(self.fd)
            tty.setraw(self.fd, termios.TCSANOW)
        return self

    def __exit__(self, *exc: object) -> None:
        self.restore()

    def restore(self) -> None:
        if self._saved is not None:
            with contextlib.suppress(termios.error, OSError):
                termios.tcsetattr(self.fd, termios.TCSADRAIN, self._saved)

    @contextlib.contextmanager
    def cooked(self) -> Iterator[None]:
        """The terminal as it was (line editing, echo, Ctrl-C) for a while."""
        if self._saved is None:
            yield
            return
        termios.tcsetattr(self.fd, termios.TCSANOW, self._saved)
        try:
            yield
        finally:
            with contextlib.suppress(termios.error, OSError):
                tty.setraw(self.fd, termios.TCSANOW)

    def read(self, timeout: float) -> bytes | None:
        """Bytes available within ``timeout`` seconds (b"" if none); None at end of input."""
        try:
            ready, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
        except InterruptedError:
            return b""
        if not ready:
            return b""
        data = os.read(self.fd, 1024)
        return data if data else None

    def read_line(self) -> bytes | None:
        """One line (without its end); None at end of input."""
        line = bytearray()
        while True:
            b = os.read(self.fd, 1)
            if not b:
                return bytes(line) if line else None
            if b in (b"\n", b"\r"):
                return bytes(line)
            line += b


@contextlib.contextmanager
def _termination_signals() -> Iterator[None]:
    """SIGTERM / SIGHUP raise :class:`Terminated` (main thread only), once: a second
    signal does not interrupt the cleanup the first one started."""
    fired: list[int] = []

    def handler(signum: int, frame: Any) -> None:
        if not fired:
            fired.append(signum)
            raise Terminated(signum)

    saved = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):
        with contextlib.suppress(ValueError):  # not the main thread: leave them
            saved[sig] = signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig, old in saved.items():
            signal.signal(sig, old)


class Screen:
    """A scrolling log above one live status line (plain lines when not a terminal)."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.is_tty = out.isatty()
        self._status = ""
        self._last_plain = -math.inf

    def _write(self, text: str) -> None:
        with contextlib.suppress(OSError, ValueError):
            self.out.write(text)
            self.out.flush()

    def message(self, text: str) -> None:
        if self.is_tty:
            lines = "".join(f"\r\x1b[K{line}\r\n" for line in text.splitlines())
            self._write(lines + self._fit(self._status))
        else:
            self._write(text + "\n")

    def status(self, text: str, sim_time: float) -> None:
        self._status = text
        if self.is_tty:
            self._write("\r\x1b[K" + self._fit(text))
        elif sim_time - self._last_plain >= 1.0 - 1e-9:
            self._last_plain = sim_time
            self._write(text + "\n")

    def prompt(self, text: str) -> None:
        self._write(("\r\x1b[K" if self.is_tty else "") + text)

    def close(self) -> None:
        if self.is_tty:
            self._write("\r\x1b[K" + self._status + "\r\n")

    def _fit(self, text: str) -> str:
        """Cut to the terminal's width (one line: the next ``\\r`` must overwrite it all)."""
        try:
            width = os.get_terminal_size(self.out.fileno()).columns
        except (OSError, ValueError, AttributeError):
            width = shutil.get_terminal_size((80, 24)).columns
        return text[: max(width - 1, 10)]


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
    with _termination_signals(), KeyInput(fd) as term:
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
                    self._record(_read_label(self.term, self.screen, self.buf), pose)
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


def _read_label(term: KeyInput, screen: Screen, buf: bytearray) -> str | None:
    """A label: a line already typed ahead in ``buf``, else read at a ``label:`` prompt."""
    for i, b in enumerate(buf):
        if b in (0x0A, 0x0D):
            line = bytes(buf[:i])
            del buf[: i + 1]
            if b == 0x0D and buf[:1] == b"\n":
                del buf[:1]
            return _edit(line).strip()
    pending = _edit(bytes(buf))
    buf.clear()
    screen.prompt("label: " + pending)
    try:
        with term.cooked():
            rest = term.read_line()
    except KeyboardInterrupt:
        screen.message("")
        return None
    if rest is None:
        return None
    return (pending + _edit(rest)).strip()


def _edit(raw: bytes) -> str:
    """Apply backspaces typed in raw mode; drop other control characters."""
    out: list[str] = []
    for ch in raw.decode("utf-8", errors="replace"):
        if ch in ("\x7f", "\x08"):
            if out:
                out.pop()
        elif ch.isprintable():
            out.append(ch)
    return "".join(out)


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
