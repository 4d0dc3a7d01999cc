"""Every run directory ends with a result.json: signals, exceptions, broken pipes, failed
plots. Real processes and real signals."""

from __future__ import annotations

import json
import random
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Literal

import py_trees
import pytest

from agv_mission.behaviors.ports import NodePorts
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.directory import ResultNotWritten, run_in, run_under
from agv_mission.missions.report.outputs import RunDirError, make_run_dir, write_run
from agv_mission.missions.run.runner import run_mission
from agv_mission.navigation.handle import RobotHandle
from agv_mission.registry import registry
from mission_texts import ENDLESS_PATROL, mission_file, tb3_mission

EXE = [sys.executable, "-m", "agv_mission.cli"]

# Long enough to be stopped mid-way (a million rounds; the time limit ends it).
LONG = tb3_mission(ENDLESS_PATROL, limits="{time: 600.0}")

# Drives into the wall ahead: a collision ends it (about 20 simulated seconds).
CRASH = tb3_mission(
    "{type: wander, duration: 60.0, min_range: 0.01, sector: 5}", limits="{time: 60.0}"
) + (
    # Where the blind wander first touches a wall depends on its exact path: the sensors
    # this crash was found with (noise-free encoders, a constant 1 cm lidar noise).
    "simulation: {ideal: true, lidar_noise: 0.01}\n"
)

GO_SHORT = "{type: go_to, pose: {x: -1.7, y: -0.5, yaw: 0.0}}"
SHORT = tb3_mission(GO_SHORT, limits="{time: 30.0}")


def start_run(mission: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [*EXE, "run", str(mission), "--output", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for_stepping(out: Path, deadline: float = 120.0) -> None:
    """Until the run's bag is open (the observers start just before the first step), then
    a little more: a loaded machine may take seconds to build the robot before that."""
    end = time.monotonic() + deadline
    while not any(out.glob("*/bag/*")):
        assert time.monotonic() < end, "the run never opened its bag"
        time.sleep(0.05)
    time.sleep(1.0)


def only_result(out: Path) -> dict:
    [run_dir] = list(out.iterdir())
    return json.loads((run_dir / "result.json").read_text())


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_a_signal_mid_run_ends_it_aborted_with_a_result(
    tmp_path: Path, sig: signal.Signals, code: int
) -> None:
    out = tmp_path / "out"
    proc = start_run(mission_file(tmp_path, LONG), out)
    assert proc.stdout is not None
    assert "task(s) in" in proc.stdout.readline()  # the run directory is made
    wait_for_stepping(out)
    proc.send_signal(sig)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, stderr
    assert "Traceback" not in stderr
    result = only_result(out)
    assert result["status"] == "aborted" and sig.name in result["reason"] or sig == signal.SIGINT
    assert result["tasks"][0]["status"] == "aborted"
    assert result["sim_time"] > 0
    [run_dir] = list(out.iterdir())
    assert {"result.json", "trajectory.csv", "mission.yaml", "run.png"} <= {
        p.name for p in run_dir.iterdir()
    }


def test_signals_at_random_moments_never_leave_a_run_directory_without_a_result(
    tmp_path: Path,
) -> None:
    rng = random.Random(11)
    mission = mission_file(tmp_path, SHORT)
    for i in range(4):
        out = tmp_path / f"out{i}"
        sig = rng.choice([signal.SIGTERM, signal.SIGINT])
        proc = start_run(mission, out)
        time.sleep(rng.uniform(0.0, 5.0))
        proc.send_signal(sig)
        _, stderr = proc.communicate(timeout=120)
        assert "Traceback" not in stderr
        dirs = list(out.iterdir()) if out.exists() else []
        if not dirs:  # stopped before a run directory was made
            assert proc.returncode in (-sig, 130, 143, 0), (proc.returncode, stderr)
            continue
        result = json.loads((dirs[0] / "result.json").read_text())
        expected = {"succeeded": {0}, "failed": {1}, "aborted": {130, 143}}[result["status"]]
        assert proc.returncode in expected, (proc.returncode, result["status"], stderr)


def test_a_closed_stdout_keeps_the_exit_code(tmp_path: Path) -> None:
    """``agv-mission run ... | head -1``: the reader goes away, the exit code stays."""
    out = tmp_path / "out"
    proc = start_run(mission_file(tmp_path, SHORT), out)
    assert proc.stdout is not None
    proc.stdout.readline()
    proc.stdout.close()
    assert proc.wait(timeout=300) == 0
    assert proc.stderr is not None and "Traceback" not in proc.stderr.read()
    assert only_result(out)["status"] == "succeeded"


def test_after_a_collision_the_task_is_failed_not_running(tmp_path: Path) -> None:
    blind = ["stack.collision_monitor.enabled=false"]  # it would stop short of the wall
    record = run_mission(load_mission(mission_file(tmp_path, CRASH), blind))
    assert record.status == "failed" and "collision" in (record.reason or "")
    assert record.tasks[0]["status"] == "failed"
    assert "collision" in record.tasks[0]["reason"]


class _FailAtStart:
    """An observer whose start fails: the run fails before its first trajectory row."""

    def on_start(self, start: object) -> None:
        raise RuntimeError("observer broke")

    def on_step(self, sample: object) -> None: ...

    def on_end(self, record: object) -> None: ...


def test_an_exception_before_the_first_row_still_gives_a_result(tmp_path: Path) -> None:
    loaded = load_mission(mission_file(tmp_path, SHORT))
    run_dir = make_run_dir(tmp_path / "out", loaded.name)
    record = run_mission(loaded, run_dir, observers=[_FailAtStart()])
    assert record.status == "error" and "observer broke" in (record.reason or "")
    assert record.trajectory.shape == (0, 9)
    result = write_run(run_dir, loaded, record)
    assert json.loads((run_dir / "result.json").read_text())["status"] == "error"
    assert result["metrics"]["localization"]["position_rmse"] is None


class _RefusesToStart(py_trees.behaviour.Behaviour):
    """A third-party node that cannot start (as one whose device is unreachable)."""

    class Config(NodePorts):
        type: Literal["refuses_to_start"] = "refuses_to_start"

    def __init__(self, name: str, handle: RobotHandle) -> None:
        raise RuntimeError("the node's device cannot be reached")

    def update(self) -> py_trees.common.Status:
        return py_trees.common.Status.SUCCESS


def test_a_failing_set_up_still_gives_a_result(tmp_path: Path) -> None:
    """The mission is valid, but one of its nodes fails while the run is set up."""
    if "refuses_to_start" not in registry.names("behavior"):
        registry.register("behavior", "refuses_to_start")(_RefusesToStart)
    text = SHORT.replace(
        f"tasks:\n  - {GO_SHORT}\n",
        "tree: {type: sequence, children: [{type: refuses_to_start}]}\n",
    )
    loaded = load_mission(mission_file(tmp_path, text))
    record = run_mission(loaded, make_run_dir(tmp_path / "out", loaded.name))
    assert record.status == "error" and "device cannot be reached" in (record.reason or "")
    assert record.trajectory.shape == (0, 9) and record.sim_time == 0.0


def test_a_plot_that_cannot_be_written_keeps_the_result(tmp_path: Path) -> None:
    loaded = load_mission(mission_file(tmp_path, SHORT))
    record = run_mission(loaded)
    run_dir = make_run_dir(tmp_path / "out", loaded.name)
    (run_dir / "run.png").mkdir()  # the plot's rename fails, as on a full disk
    result = write_run(run_dir, loaded, record)
    written = json.loads((run_dir / "result.json").read_text())
    assert written["status"] == "succeeded"
    assert written["output_errors"] and written["output_errors"][0].startswith("run.png")
    assert result["output_errors"] == written["output_errors"]
    assert (run_dir / "trajectory.csv").is_file()


# The run loop fails inside a real process: an internal error, exit 3, status error.
INTERNAL_ERROR = """
import sys
from agv_mission import cli
from agv_mission.missions.run import runner

def broken_step(self):
    raise ZeroDivisionError("a bug in the loop")

runner.MissionRun.step = broken_step
sys.argv = ["agv-mission", "run", sys.argv[1], "--output", sys.argv[2]]
cli.main()
"""


def test_an_internal_error_exits_3_with_status_error(tmp_path: Path) -> None:
    script = tmp_path / "broken.py"
    script.write_text(INTERNAL_ERROR)
    out = tmp_path / "out"
    r = subprocess.run(
        [sys.executable, str(script), str(mission_file(tmp_path, SHORT)), str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 3, r.stderr
    assert "Traceback" not in r.stderr
    result = only_result(out)
    assert result["status"] == "error" and "ZeroDivisionError" in result["reason"]


def test_tree_txt_has_no_terminal_colour_codes(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = subprocess.run(
        [*EXE, "run", str(mission_file(tmp_path, SHORT)), "--output", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**__import__("os").environ, "FORCE_COLOR": "1", "TERM": "xterm-256color"},
    )
    assert r.returncode == 0, r.stderr
    [run_dir] = list(out.iterdir())
    text = (run_dir / "tree.txt").read_text()
    assert "mission" in text and "\x1b[" not in text


def test_a_run_directory_that_cannot_be_made_or_hold_its_result_is_said_so(
    tmp_path: Path,
) -> None:
    loaded = load_mission(mission_file(tmp_path, SHORT), ["limits.time=1.0"])
    (tmp_path / "a_file").write_text("")
    with pytest.raises(RunDirError, match="cannot create a run directory"):
        run_under(tmp_path / "a_file", loaded)
    run_dir = tmp_path / "run"
    (run_dir / "result.json").mkdir(parents=True)  # the rename over it fails
    with pytest.raises(ResultNotWritten, match="result.json"):
        run_in(run_dir, loaded)
    assert (run_dir / "mission.yaml").is_file()  # written before the run
