"""The crowd walking in a process of its own (:mod:`agv_mission.missions.crowd_process`): the
run is the one of a single process, byte for byte, and a stopped or failing crowd process
still leaves the run's result. Real processes through the command line (``auto`` never
forks inside the test runner, which runs threads)."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from agv_mission.missions.crowd_process import OWN_PROCESS_FROM, own_process

EXE = [sys.executable, "-m", "agv_mission.cli"]

# A burger crossing the house among twelve people: ten wandering the living room, one
# walking a route from t = 2 s, one who pays nobody any attention.
CROWD = """
name: crowd-apart
world: small_house
start: {{x: -1.5, y: -2.0, yaw: 0.0}}
seed: 3
simulation: {{processes: {processes}}}
people:
  - {{count: 10, area: livingroom}}
  - {{behaviour: route, route: [{{x: -5.0, y: -4.0}}, {{x: -5.0, y: 0.0}}], start_time: 2.0}}
  - {{behaviour: route, route: [{{x: 1.0, y: -4.5}}, {{x: 1.0, y: 0.5}}], attentive: false}}
tasks:
  - {{type: patrol, loops: {loops}, waypoints: [{{x: 3.5, y: -2.0, yaw: 0.0}},
      {{x: -1.5, y: -2.0, yaw: 3.1416}}]}}
limits: {{time: {limit}}}
"""

TIMED = {"wall_time", "real_time_factor", "crowd_process", "run_dir"}

# The crowd fails in its own process from t = 3 s.
FAIL_IN_THE_CROWD_PROCESS = """
import os, sys
from agv_mission import cli
from agv_mission.world import crowd

FIRST = os.getpid()
decide = crowd.Crowd._decide

def broken(self, dt, robots):
    if os.getpid() != FIRST and self.time >= 3.0:
        raise ZeroDivisionError("a bug in the crowd process")
    decide(self, dt, robots)

crowd.Crowd._decide = broken
sys.argv = ["agv-mission", "run", sys.argv[1], "--output", sys.argv[2]]
cli.main()
"""


def untimed(value: object) -> object:
    """``value`` without what the wall clock measured (and where the crowd walked)."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if k not in TIMED and "_ms" not in k}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def only_run(out: Path) -> Path:
    [run_dir] = list(out.iterdir())
    return run_dir


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


def test_one_process_or_a_crowd_of_its_own_is_decided_safely() -> None:
    assert not own_process(1, 50)  # the user asked for one process
    assert not own_process(2, OWN_PROCESS_FROM - 1)  # too few people to pay for it
    assert own_process(2, OWN_PROCESS_FROM) == (sys.platform != "win32")
    assert not own_process("auto", 50)  # the test runner runs threads: never forks


def test_people_walk_the_same_in_a_process_of_their_own(tmp_path: Path) -> None:
    """Trajectories and people.csv byte for byte, the result and the bag the same."""
    runs = {}
    for processes in (1, 2):
        mission = tmp_path / f"crowd{processes}.yaml"
        mission.write_text(CROWD.format(processes=processes, loops=1, limit=25.0))
        out = tmp_path / f"p{processes}"
        r = subprocess.run(
            [*EXE, "run", str(mission), "--output", str(out)],
            capture_output=True,
            text=True,
            timeout=600,
        )
        assert r.returncode in (0, 1), r.stderr
        runs[processes] = only_run(out)
    one, two = runs[1], runs[2]
    a = json.loads((one / "result.json").read_text())
    b = json.loads((two / "result.json").read_text())
    assert a["metrics"]["people"]["crowd_process"] is False
    assert b["metrics"]["people"]["crowd_process"] is True
    assert a["metrics"]["people"]["people"] == 12 and a["metrics"]["distance_driven"] > 1.0
    assert untimed(a) == untimed(b)
    for name in ("trajectory.csv", "people.csv"):
        assert (one / name).read_bytes() == (two / name).read_bytes()
    counts = []
    for run in (one, two):
        with AnyReader([run / "bag"]) as reader:
            counts.append({c.topic: c.msgcount for c in reader.connections})
    assert counts[0] == counts[1] and counts[0]["/people"] > 50


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="lists processes through /proc")
def test_a_signal_ends_a_run_whose_crowd_walks_apart(tmp_path: Path) -> None:
    mission = tmp_path / "long.yaml"
    mission.write_text(CROWD.format(processes=2, loops=1000, limit=600.0))
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
    assert len(_processes_of(mission)) == 2  # the run and its crowd
    proc.send_signal(signal.SIGINT)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    result = json.loads((only_run(out) / "result.json").read_text())
    assert result["status"] == "aborted" and result["metrics"]["people"]["crowd_process"]
    assert result["sim_time"] > 1.0 and (only_run(out) / "people.csv").stat().st_size > 100
    end = time.monotonic() + 30.0
    while _processes_of(mission):
        assert time.monotonic() < end, "the crowd process outlived its run"
        time.sleep(0.1)


def test_a_failure_in_the_crowd_process_ends_the_run_with_status_error(tmp_path: Path) -> None:
    mission = tmp_path / "crowd.yaml"
    mission.write_text(CROWD.format(processes=2, loops=1, limit=20.0))
    script = tmp_path / "broken.py"
    script.write_text(FAIL_IN_THE_CROWD_PROCESS)
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
        "the crowd process failed: ZeroDivisionError: a bug in the crowd process"
        in (result["reason"])
    )
    assert 2.5 <= result["sim_time"] <= 3.5
    assert (only_run(out) / "people.csv").exists()
