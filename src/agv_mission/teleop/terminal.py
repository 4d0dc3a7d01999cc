"""The terminal side of teleop: keys to twists (turtlebot3_teleop_key's steps), raw
keyboard input, the live status line, the label prompt, and clean-up on every way out."""

from __future__ import annotations

import contextlib
import math
import os
import select
import shutil
import signal
import termios
import tty
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, TextIO

from agv_mission.planners.base import VelocityLimits

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
def termination_signals() -> Iterator[None]:
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


def read_label(term: KeyInput, screen: Screen, buf: bytearray) -> str | None:
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
