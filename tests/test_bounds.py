"""Resource bounds: input that would take unbounded memory or time is refused, quickly."""

from __future__ import annotations

import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import run_mission
from cli_in_process import agv
from mission_texts import ENDLESS_PATROL, mission_file, tb3_mission

EXE = [sys.executable, "-m", "agv_mission.cli"]
MISSION = "tasks: [{type: wander, duration: 5}]\n"

LAZY_PATROL = tb3_mission(ENDLESS_PATROL, limits="{time: 25.0}")


def cli(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """The program in a process of its own: a read that blocked would hit the timeout."""
    return subprocess.run([*EXE, *args], capture_output=True, text=True, timeout=timeout)


def problem_of(path: Path) -> str:
    with pytest.raises(MissionError) as info:
        load_mission(path)
    [p] = info.value.problems
    assert p.file == str(path) and p.line is None
    return p.message


def test_a_mission_file_over_the_cap_is_refused_before_parsing(tmp_path: Path) -> None:
    path = tmp_path / "huge.yaml"
    path.write_text(MISSION + "# " + "x" * (5 * 1024 * 1024) + "\n")
    assert "too large" in problem_of(path) and "4 MB" in problem_of(path)


def test_devices_fifos_and_directories_are_refused_without_reading(tmp_path: Path) -> None:
    fifo = tmp_path / "mission.fifo"
    os.mkfifo(fifo)
    assert "FIFO, not a regular file" in problem_of(fifo)  # would block on open()
    assert "device or socket, not a regular file" in problem_of(Path("/dev/zero"))
    assert "Is a directory" in problem_of(tmp_path)
    world = tmp_path / "world_fifo.yaml"
    os.mkfifo(world)
    mission = tmp_path / "m.yaml"
    mission.write_text(f"world: {world}\n" + MISSION)
    with pytest.raises(MissionError) as info:
        load_mission(mission)
    [p] = info.value.problems
    assert (p.line, p.field) == (1, "world") and "FIFO, not a regular file" in p.message


def test_validate_refuses_dev_zero_and_a_fifo_with_exit_2(tmp_path: Path) -> None:
    fifo = tmp_path / "m.yaml"
    os.mkfifo(fifo)
    r = cli("validate", "/dev/zero", str(fifo), timeout=60)
    assert r.returncode == 2, r.stderr
    assert "/dev/zero: cannot read: a device or socket" in r.stderr
    assert f"{fifo}: cannot read: a FIFO" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_patrol_loops_lazily(tmp_path: Path) -> None:
    """A million loops hold as many nodes as one; the time limit ends the patrol."""
    record = run_mission(load_mission(mission_file(tmp_path, LAZY_PATROL, "lazy")))
    assert record.status == "failed" and "time limit" in (record.reason or "")
    assert len(record.tree_text.splitlines()) < 30
    task = record.tasks[0]
    assert task["waypoints_planned"] == 2_000_000
    seen = [(w["loop"], w["waypoint"]) for w in task["waypoints"]]
    assert len(seen) >= 4
    assert seen == [(1 + i // 2, 1 + i % 2) for i in range(len(seen))]  # loop numbers count up


def test_costmap_resolution_is_bounded_in_validate_too(tmp_path: Path) -> None:
    path = tmp_path / "fine.yaml"
    path.write_text("stack: {costmap: {resolution: 0.000001}}\n" + MISSION)
    r = agv("validate", str(path))
    assert r.returncode == 2
    assert f"{path}:1: stack.costmap.resolution" in r.stderr and "cells" in r.stderr


@pytest.mark.parametrize("kind", ["a file", "under a file", "not permitted"])
def test_output_that_cannot_hold_a_run_directory_exits_2(tmp_path: Path, kind: str) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text(MISSION)
    blocker = tmp_path / "blocker"
    blocker.write_text("")
    output = {
        "a file": blocker,
        "under a file": blocker / "runs",
        "not permitted": Path("/sys/kernel/agv-mission-runs"),  # even root may not
    }[kind]
    r = agv("run", str(mission), "--output", str(output))
    assert r.returncode == 2, r.stdout + r.stderr
    assert f"--output '{output}': cannot create a run directory" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_read_only_output_exits_2(tmp_path: Path) -> None:
    mission = tmp_path / "m.yaml"
    mission.write_text(MISSION)
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    r = agv("run", str(mission), "--output", str(ro))
    assert r.returncode == 2 and "cannot create a run directory" in r.stderr


def test_loading_never_blocks_on_a_fifo(tmp_path: Path) -> None:
    """The FIFO check happens before open(): a writer never appears, nothing waits."""
    fifo = tmp_path / "rooms.fifo"
    os.mkfifo(fifo)
    mission = tmp_path / "m.yaml"
    mission.write_text(f"rooms: {fifo}\n" + MISSION)
    outcome: list[BaseException] = []

    def load() -> None:
        try:
            load_mission(mission)
        except MissionError as exc:
            outcome.append(exc)

    t = threading.Thread(target=load, daemon=True)
    t.start()
    t.join(60)
    assert outcome and "FIFO" in str(outcome[0].problems[0])
