"""A fleet's robots deciding in several processes (:mod:`agv_mission.missions.run.forked_team`): the
run is the one of a single process, and a stopped or failing run still ends with every
robot's result. Real processes through the command line (``auto`` never forks inside the
test runner, which runs threads)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.team import team_size

EXE = [sys.executable, "-m", "agv_mission.cli"]
SCENARIOS = Path(__file__).parent / "scenarios"
AISLE = (Path(__file__).parent / "worlds" / "fleet_aisle.yaml").resolve()

# Three burgers patrolling in the two rooms and the aisle's mouth for ten minutes: long
# enough to be stopped mid-way.
LONG = f"""
name: fleet-long
world: {AISLE}
seed: 4
stack: {{localization: {{type: ground_truth}}, local_planner: {{type: mpc}}}}
simulation: {{processes: 2}}
robots:
  - name: west
    robot: burger
    start: {{x: -5.0, y: 0.8, yaw: 0.0}}
    tasks: [{{type: patrol, loops: 1000000, waypoints: [{{x: -4.0, y: 0.8, yaw: 0.0}},
             {{x: -5.0, y: 0.8, yaw: 3.1416}}]}}]
  - name: south
    robot: burger
    start: {{x: -5.0, y: -0.8, yaw: 0.0}}
    tasks: [{{type: patrol, loops: 1000000, waypoints: [{{x: -4.0, y: -0.8, yaw: 0.0}},
             {{x: -5.0, y: -0.8, yaw: 3.1416}}]}}]
  - name: east
    robot: burger
    start: {{x: 5.0, y: 0.0, yaw: 3.1416}}
    tasks: [{{type: patrol, loops: 1000000, waypoints: [{{x: 4.0, y: 0.0, yaw: 3.1416}},
             {{x: 5.0, y: 0.0, yaw: 0.0}}]}}]
limits: {{time: 600.0}}
"""

# The loop fails inside the second process only: the run ends with status error.
FAIL_IN_A_ROBOT_PROCESS = """
import os, sys
from agv_mission import cli
from agv_mission.missions.run import robot_run

FIRST = os.getpid()
decide = robot_run.RobotRun.decide

def broken(self, now):
    if os.getpid() != FIRST and now >= 3.0:
        raise ZeroDivisionError("a bug in a robot process")
    decide(self, now)

robot_run.RobotRun.decide = broken
sys.argv = ["agv-mission", "run", sys.argv[1], "--output", sys.argv[2]]
cli.main()
"""

TIMED = {"wall_time", "real_time_factor"}


def untimed(value: object) -> object:
    """``value`` without what the wall clock measured (and the process count)."""
    if isinstance(value, dict):
        return {
            k: untimed(v)
            for k, v in value.items()
            if k not in TIMED and "_ms" not in k and k not in ("processes", "when", "run_dir")
        }
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def run_cli(mission: Path, out: Path, *sets: str) -> subprocess.CompletedProcess:
    args = [*EXE, "run", str(mission), "--output", str(out)]
    for s in sets:
        args += ["--set", s]
    return subprocess.run(args, capture_output=True, text=True, timeout=600)


def topic_counts(bag: Path) -> dict[str, int]:
    with AnyReader([bag]) as reader:
        return {c.topic: c.msgcount for c in reader.connections}


def only_run(out: Path) -> Path:
    [run_dir] = list(out.iterdir())
    return run_dir


def test_auto_decides_alone_where_forking_is_unsafe_or_pointless() -> None:
    assert team_size("auto", 1, None) == 1  # one robot
    assert team_size(4, 1, None) == 1
    assert team_size(1, 8, None) == 1
    # a control that commands robots (the service, teleop) needs every robot here
    assert team_size(2, 8, object()) == 1


FAST_LIDAR = """\
wheel_radius: 0.033
wheel_separation: 0.16
footprint_radius: 0.105
max_linear_velocity: 0.22
max_angular_velocity: 2.84
encoder: {ticks_per_meter: 19754.0}
lidar: {beams: 180, range_min: 0.12, range_max: 3.5, rate: 25.0, height: 0.17}
"""


@pytest.mark.parametrize(
    ("scenario", "fast_lidar"),
    [
        # the first process steps the physics, the robot process mirrors its world (34 s;
        # the signal and failure tests below fork the same team in make test)
        pytest.param("fleet_crossing", None, marks=pytest.mark.slow),
        # a lidar scans between control steps: every process steps the physics (22 s)
        pytest.param("fleet_head_on_aisle", "west", marks=pytest.mark.slow),
    ],
)
def test_a_fleet_in_two_processes_runs_as_in_one(
    tmp_path: Path, scenario: str, fast_lidar: str | None
) -> None:
    """Trajectories byte for byte, the result and the bag the same, whether the robots
    decide in one process or two (waits, yields and deadlocks broken included)."""
    mission = SCENARIOS / f"{scenario}.yaml"
    sets = []
    if fast_lidar is not None:
        robot = tmp_path / "fast.robot.yaml"
        robot.write_text(FAST_LIDAR)
        sets.append(f"robots.{fast_lidar}.robot={robot}")
    runs = {}
    for processes in (1, 2):
        out = tmp_path / f"p{processes}"
        r = run_cli(mission, out, f"simulation.processes={processes}", *sets)
        assert r.returncode == 0, r.stderr
        runs[processes] = only_run(out)
    one, two = runs[1], runs[2]
    a = json.loads((one / "result.json").read_text())
    b = json.loads((two / "result.json").read_text())
    assert a["metrics"]["processes"] == 1 and b["metrics"]["processes"] == 2
    assert a["status"] == "succeeded"
    assert a["fleet"]["deadlocks"] >= 1 and a["fleet"]["waits"]["count"] >= 1
    assert untimed(a) == untimed(b)
    assert (one / "trajectory.csv").read_bytes() == (two / "trajectory.csv").read_bytes()
    assert topic_counts(one / "bag") == topic_counts(two / "bag")


def _processes_of(mission: Path) -> list[int]:
    """The processes whose command line names ``mission`` (the run and its forks)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes()
            except OSError:
                continue
            if str(mission).encode() in cmdline:
                found.append(int(entry.name))
    return found


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="lists processes through /proc")
def test_a_signal_ends_a_run_in_two_processes_with_every_robots_result(tmp_path: Path) -> None:
    mission = tmp_path / "long.yaml"
    mission.write_text(LONG)
    assert len(load_mission(mission).robots) == 3
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [*EXE, "run", str(mission), "--output", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    end = time.monotonic() + 120.0
    while not any(out.glob("*/bag/*")):
        assert time.monotonic() < end and proc.poll() is None, "the run never started"
        time.sleep(0.05)
    time.sleep(1.5)
    assert len(_processes_of(mission)) == 2  # the run and one robot process
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    result = json.loads((only_run(out) / "result.json").read_text())
    assert result["status"] == "aborted" and result["metrics"]["processes"] == 2
    robots = result["robots"]
    assert sorted(robots) == ["east", "south", "west"]
    assert all(r["status"] == "aborted" for r in robots.values())
    assert all(r["metrics"]["distance_driven"] > 0.1 for r in robots.values())
    rows: dict[str, int] = {}
    for line in (only_run(out) / "trajectory.csv").read_text().splitlines()[1:]:
        name = line.split(",", 1)[0]
        rows[name] = rows.get(name, 0) + 1
    assert len(set(rows.values())) == 1 and sorted(rows) == sorted(robots)
    end = time.monotonic() + 30.0
    while _processes_of(mission):
        assert time.monotonic() < end, "a robot process outlived its run"
        time.sleep(0.1)


def test_a_failure_in_a_robot_process_ends_the_run_with_status_error(tmp_path: Path) -> None:
    mission = tmp_path / "long.yaml"
    mission.write_text(LONG.replace("time: 600.0", "time: 20.0"))
    script = tmp_path / "broken.py"
    script.write_text(FAIL_IN_A_ROBOT_PROCESS)
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, str(script), str(mission), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 3, r.stderr
    result = json.loads((only_run(out) / "result.json").read_text())
    assert result["status"] == "error"
    assert (
        "a robot process failed: ZeroDivisionError: a bug in a robot process" in (result["reason"])
    )
    assert sorted(result["robots"]) == ["east", "south", "west"]
    assert 2.5 <= result["sim_time"] <= 3.5
    assert os.path.exists(only_run(out) / "trajectory.csv")


def test_on_a_terminal_the_progress_bar_leaves_the_robots_their_processes(
    tmp_path: Path,
) -> None:
    """A live progress bar that redrew itself from a thread of its own made every run
    started from a terminal decide in one process (forking only from a process with no
    other thread): the bar is redrawn by the run's progress calls instead."""
    import pty

    mission = tmp_path / "short.yaml"
    mission.write_text(LONG.replace("time: 600.0", "time: 6.0"))
    out = tmp_path / "out"
    master, slave = pty.openpty()
    proc = subprocess.Popen(
        [*EXE, "run", str(mission), "--output", str(out)],
        stdout=subprocess.DEVNULL,
        stderr=slave,
    )
    os.close(slave)
    shown = b""
    while True:  # drain the terminal (the bar's redraws) until the run closes it
        try:
            chunk = os.read(master, 4096)
        except OSError:
            break
        if not chunk:
            break
        shown += chunk
    os.close(master)
    assert proc.wait(timeout=300) in (0, 1)
    assert b"sim s" in shown  # the bar was on the terminal
    result = json.loads((only_run(out) / "result.json").read_text())
    assert result["metrics"]["processes"] == 2
