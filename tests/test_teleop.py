"""``agv-mission teleop``: key logic, a piped session, and a real terminal driven through tmux."""

from __future__ import annotations

import math
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import yaml

from agv_mission.geometry import wrap_angle
from agv_mission.maps.builtin_worlds import HOUSE_SPAWN
from agv_mission.maps.recorder import (
    RECORDER_FILENAME,
    LocationRecorder,
    RecorderFile,
    open_recorders,
)
from agv_mission.maps.rooms import room_at
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.planners.base import VelocityLimits
from agv_mission.teleop.session import load_teleop_mission, teleop_mission
from agv_mission.teleop.terminal import TeleopKeys, split_keys

CLI = [sys.executable, "-m", "agv_mission.cli"]
STATUS = re.compile(
    r"room=(?P<room>\S+) x=(?P<x>[-+][\d.]+) y=(?P<y>[-+][\d.]+) yaw=(?P<yaw>[-+][\d.]+) "
)


# --------------------------------------------------------------------------- units


def test_keys_step_like_turtlebot3_teleop_key_within_the_robots_limits() -> None:
    keys = TeleopKeys.for_limits(
        VelocityLimits(max_v=0.22, max_w=2.84, max_acc_v=1.0, max_acc_w=4.0)
    )
    for key in "wi" + "w" * 20:  # w and i: faster forward, capped
        keys.press(key)
    assert keys.v == pytest.approx(0.22)
    keys.press("x")
    keys.press(",")
    assert keys.v == pytest.approx(0.176)
    for key in ("a", "j", "LEFT"):
        keys.press(key)
    assert keys.w == pytest.approx(3 * 0.284)
    for key in ("d", "l", "RIGHT", "RIGHT"):
        keys.press(key)
    assert keys.w == pytest.approx(-0.284)
    assert keys.press("k") == "stop" and keys.v == keys.w == 0.0
    for key in ",x" + "x" * 20:
        keys.press(key)
    assert keys.v == pytest.approx(-0.22)
    assert keys.press(" ") == "stop" and (keys.v, keys.w) == (0.0, 0.0)
    assert [keys.press(k) for k in ("r", "q", "\x03", "z")] == ["record", "quit", "quit", None]


def test_split_keys_reads_characters_and_arrow_keys() -> None:
    buf = bytearray(
        b"w\x1b[A\x1bOBq\x1b[5~k\xc3"
    )  # w, Up, Down (SS3), q, PageUp, k, half of a char
    assert list(split_keys(buf)) == ["w", "UP", "DOWN", "q", "k"]
    assert buf == bytearray(b"\xc3")  # kept until the rest arrives
    buf += b"\xa9"
    assert list(split_keys(buf)) == ["\u00e9"] and not buf


def test_default_mission_is_small_house_from_the_livingroom(tmp_path: Path) -> None:
    loaded = load_teleop_mission()
    assert loaded.world.name == "small_house" and loaded.robot.name == "burger"
    assert loaded.start == HOUSE_SPAWN
    assert room_at(loaded.rooms, loaded.start.x, loaded.start.y) == "livingroom"
    assert room_at(loaded.rooms, 4.7, -2.8) is None  # in the kitchen doorway
    assert loaded.mission.stack.localization.type == "amcl"  # the seed records amcl_pose
    # a mission file without tasks is fine for teleop; --world/--robot override it
    mission = tmp_path / "m.yaml"
    mission.write_text("world: small_house\nstart: kitchen\nstack: {localization: {type: amcl}}\n")
    loaded = load_teleop_mission(mission, robot="waffle")
    assert loaded.robot.name == "waffle" and loaded.mission.stack.localization.type == "amcl"
    assert room_at(loaded.rooms, loaded.start.x, loaded.start.y) == "kitchen"


def test_teleop_task_drives_under_remote_command_and_estimates() -> None:
    """The session's robot is the runner's teleop task: a control sets the command."""

    class Forward:
        steps = 0

        def before_step(self, run: MissionRun) -> None:
            if self.steps == 30:
                run.cancel("quit")
            run.handle.remote_command = (0.2, 0.0)
            self.steps += 1

    record = run_mission(teleop_mission(load_teleop_mission()), None, control=Forward())
    assert record.sim_time == pytest.approx(3.0)
    assert record.trajectory.shape == (30, 9)
    est_x = record.trajectory[-1, 4]
    assert 0.4 < est_x - HOUSE_SPAWN.x < 0.65
    assert record.trajectory[:, 7].max() == pytest.approx(0.2)
    # the kitchen wall, 0.77 m ahead of the spawn, ends in the collision monitor's slowdown
    # zone (half speed), as it would on the robot
    assert record.trajectory[-1, 7] == pytest.approx(0.1)
    assert [e["action"] for e in record.events if e["event"] == "collision_monitor"] == ["slowdown"]
    assert record.tasks[0]["type"] == "teleop" and record.status == "aborted"


def test_teleop_task_with_a_duration_ends_and_stands_still_without_commands(
    tmp_path: Path,
) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text("world: small_house\ntasks:\n  - {type: teleop, duration: 1.5}\n")
    record = run_mission(load_mission(mission), None)
    assert record.status == "succeeded" and record.sim_time == pytest.approx(1.5, abs=0.11)
    assert float(abs(record.trajectory[:, 7]).max()) == 0.0  # no command, no motion


def test_open_recorders_targets(tmp_path: Path) -> None:
    loaded = load_teleop_mission()
    [rec] = open_recorders(tmp_path, loaded.recorder, None, None)
    assert rec.path == tmp_path / RECORDER_FILENAME and len(rec) == 0
    direct = tmp_path / "direct.yaml"
    LocationRecorder(direct).record("kitchen", HOUSE_SPAWN)
    [rec] = open_recorders(None, loaded.recorder, direct, None)
    assert rec.path == direct and rec.labels == ["kitchen"]  # appends to itself
    with pytest.raises(ValueError, match="replaced by the entries"):
        open_recorders(None, loaded.recorder, direct, tmp_path / "other.yaml")
    [rec] = open_recorders(tmp_path / "run", loaded.recorder, None, direct)
    assert rec.path.parent == tmp_path / "run" and rec.labels == ["kitchen"]
    # the mission's recorder key: the run directory's copy, and the file updated in place
    mission = tmp_path / "m.yaml"
    mission.write_text("world: small_house\nrecorder: direct.yaml\n")
    run_copy, in_place = open_recorders(tmp_path / "run2", load_teleop_mission(mission).recorder)
    assert run_copy.path == tmp_path / "run2" / RECORDER_FILENAME and in_place.path == direct
    assert run_copy.labels == in_place.labels == ["kitchen"]


# --------------------------------------------------------------------------- sessions


def test_piped_session_records_and_quits(tmp_path: Path) -> None:
    old = tmp_path / "old.yaml"
    LocationRecorder(old).record("bedroom", HOUSE_SPAWN)
    r = subprocess.run(
        [
            *CLI,
            "teleop",
            "--output",
            str(tmp_path / "runs"),
            "--append",
            str(old),
            "--time-scale",
            "50",
        ],
        input=b"wwwww" + b"r" + b"livingroom\n" + b"q",
        capture_output=True,
        timeout=120,
    )
    out = r.stdout.decode()
    assert r.returncode == 0, out + r.stderr.decode()
    assert "recorded 'livingroom'" in out and "teleop ended (quit)" in out
    [run_dir] = (tmp_path / "runs").iterdir()
    doc = yaml.safe_load((run_dir / RECORDER_FILENAME).read_text())
    assert list(doc) == ["bedroom", "livingroom"]
    assert (run_dir / "trajectory.csv").exists() and (run_dir / "mission.yaml").exists()
    header = (run_dir / "trajectory.csv").read_text().splitlines()[0]
    assert header.endswith(",v,w,battery")
    # end of input quits too; a bad --append file is invalid input
    bad = tmp_path / "bad.yaml"
    bad.write_text("kitchen: 3\n")
    r = subprocess.run(
        [*CLI, "teleop", "--append", str(bad)],
        stdin=subprocess.DEVNULL,
        capture_output=True,
        timeout=120,
    )
    assert r.returncode == 2 and "kitchen: expected exactly the keys" in r.stderr.decode()


TMUX = shutil.which("tmux")


class Tmux:
    """One detached tmux session on a private server, read with capture-pane."""

    def __init__(self, socket: Path, session: str) -> None:
        self.base = [TMUX or "tmux", "-S", str(socket), "-f", "/dev/null"]
        self.session = session

    def run(self, *args: str) -> str:
        r = subprocess.run([*self.base, *args], capture_output=True, text=True, timeout=10)
        return r.stdout

    def keys(self, *keys: str) -> None:
        self.run("send-keys", "-t", self.session, *keys)

    def screen(self) -> str:
        return self.run("capture-pane", "-p", "-J", "-t", self.session)

    def wait_for(self, pattern: str, timeout: float = 30.0) -> re.Match[str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            match = re.search(pattern, self.screen(), re.MULTILINE)
            if match:
                return match
            time.sleep(0.02)
        raise AssertionError(f"{pattern!r} never appeared; screen:\n{self.screen()}")

    def status(self) -> dict[str, float | str]:
        for line in reversed(self.screen().splitlines()):
            m = STATUS.search(line)
            if m:
                d: dict[str, float | str] = {
                    k: float(v) for k, v in m.groupdict().items() if k != "room"
                }
                d["room"] = m["room"]
                return d
        raise AssertionError(f"no status line; screen:\n{self.screen()}")


@pytest.fixture
def tmux(tmp_path: Path) -> Iterator[Tmux]:
    if TMUX is None:
        pytest.skip("tmux is not installed (apt-get install -y tmux): the terminal test needs it")
    sockets = Path(tempfile.mkdtemp(prefix="agv-tmux-"))  # short: a socket path has a limit
    t = Tmux(sockets / "socket", "teleop")
    try:
        yield t
    finally:
        t.run("kill-server")
        shutil.rmtree(sockets, ignore_errors=True)


def _start(tmux: Tmux, tmp_path: Path, *args: str) -> None:
    """Run the teleop in the pane from a script that notes the terminal settings before
    and after, the exit code, and the teleop's pid."""
    script = tmp_path / "session.sh"
    command = shlex.join([*CLI, "teleop", *args])
    script.write_text(
        f"cd {shlex.quote(str(tmp_path))}\n"
        # a pane just made may not answer stty at once on a loaded machine: ask again
        "for i in 1 2 3 4 5 6 7 8 9 10; do stty -g > stty_before && [ -s stty_before ] && break;"
        " sleep 0.2; done\n"
        f"sh -c 'echo $$ > pid; exec \"$@\"' sh {command}\n"
        "echo TELEOP_EXIT=$?\n"
        "stty -g > stty_after\n"
        "sleep 60\n"
    )
    tmux.run(
        "new-session",
        "-d",
        "-s",
        tmux.session,
        "-x",
        "200",
        "-y",
        "50",
        f"sh {shlex.quote(str(script))}",
    )
    tmux.wait_for(r"room=livingroom")


def _turn_to(tmux: Tmux, yaw: float, tol: float = 0.05) -> None:
    """Turn on the spot to ``yaw``: fast, then one-step taps to correct any overshoot
    (which grows when the machine is loaded and the screen is read late)."""

    def error() -> float:
        return wrap_angle(yaw - float(tmux.status()["yaw"]))

    deadline = time.monotonic() + 30
    presses = 2
    while time.monotonic() < deadline:  # a loaded machine may need more taps than six
        start = error()
        if abs(start) <= tol:
            return
        tmux.keys(("a" if start > 0 else "d") * presses)
        while True:  # until reached or crossed
            e = error()
            if abs(e) <= tol or e * start < 0:
                break
            assert time.monotonic() < deadline, tmux.screen()
            time.sleep(0.005)
        tmux.keys("s")
        _settle(tmux)
        presses = 1
    assert abs(error()) <= 2 * tol, tmux.screen()


def _drive_until(tmux: Tmux, done: Callable[[dict], bool], presses: int = 10) -> None:
    tmux.keys("w" * presses)
    deadline = time.monotonic() + 30
    while not done(tmux.status()):
        assert time.monotonic() < deadline, tmux.screen()
        time.sleep(0.005)
    tmux.keys("s")


def _settle(tmux: Tmux) -> dict[str, float | str]:
    """Wait until the robot stands still (the status line stops changing)."""
    last = None
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        time.sleep(0.1)
        s = tmux.status()
        if last is not None and (s["x"], s["y"], s["yaw"]) == (last["x"], last["y"], last["yaw"]):
            return s
        last = s
    raise AssertionError(f"the robot never stood still; screen:\n{tmux.screen()}")


@pytest.mark.skipif(TMUX is None, reason="tmux is not installed (apt-get install -y tmux)")
def test_tmux_drive_into_the_kitchen_record_it_and_quit(tmux: Tmux, tmp_path: Path) -> None:
    recorder = tmp_path / "rooms" / RECORDER_FILENAME
    _start(tmux, tmp_path, "--recorder", str(recorder), "--time-scale", "8")
    # From the spawn (3.83, -1.23, 0) in the livingroom: south to the kitchen doorway's
    # line (y -3.4 .. -2.2 in the wall at x 4.7), then east through it.
    _turn_to(tmux, -math.pi / 2)
    _drive_until(tmux, lambda s: s["y"] <= -2.75)
    _turn_to(tmux, 0.0)
    _drive_until(tmux, lambda s: s["x"] >= 5.6)
    here = _settle(tmux)
    assert here["room"] == "kitchen", tmux.screen()

    tmux.keys("r")
    tmux.wait_for(r"label: *$")
    tmux.keys("kitchen", "Enter")
    tmux.wait_for(r"recorded 'kitchen' at")
    tmux.keys("q")
    tmux.wait_for(r"TELEOP_EXIT=0")
    screen = tmux.screen()
    assert f"recorder file: {recorder} (1 entry" in screen.replace("\n", "")
    assert "warning" not in screen and "CONTACT" not in screen

    doc = yaml.safe_load(recorder.read_text())
    assert list(doc) == ["kitchen"]
    assert list(doc["kitchen"]) == ["position", "orientation"]
    assert list(doc["kitchen"]["position"]) == ["x", "y", "z"]
    assert list(doc["kitchen"]["orientation"]) == ["x", "y", "z", "w"]
    pose = LocationRecorder(recorder, RecorderFile.read(recorder)).entries["kitchen"]
    kitchen = load_teleop_mission().rooms["kitchen"]
    assert kitchen.contains(pose.x, pose.y)
    assert (pose.x, pose.y) == pytest.approx((here["x"], here["y"]), abs=2e-3)
    # the terminal is as it was
    assert (tmp_path / "stty_before").read_text() == (tmp_path / "stty_after").read_text()


@pytest.mark.skipif(TMUX is None, reason="tmux is not installed (apt-get install -y tmux)")
def test_tmux_sigterm_restores_the_terminal_and_keeps_the_file(tmux: Tmux, tmp_path: Path) -> None:
    _start(tmux, tmp_path, "--output", str(tmp_path / "runs"), "--time-scale", "8")
    tmux.keys("wwa")
    tmux.keys("r")
    tmux.wait_for(r"label: *$")
    tmux.keys("living room", "Enter")  # any label: here a free one with a space
    tmux.wait_for(r"recorded 'living room' at")
    tmux.keys("ww")
    time.sleep(0.3)
    pid = int((tmp_path / "pid").read_text())
    subprocess.run(["kill", "-TERM", str(pid)], check=True)
    tmux.wait_for(r"TELEOP_EXIT=143")
    assert "teleop ended (terminated)" in tmux.screen()
    assert (tmp_path / "stty_before").read_text() == (tmp_path / "stty_after").read_text()
    [run_dir] = (tmp_path / "runs").iterdir()
    doc = yaml.safe_load((run_dir / RECORDER_FILENAME).read_text())
    assert list(doc) == ["living room"]
    assert (run_dir / "trajectory.csv").exists()
