"""Plugins: every built-in keeps its slot's contract, and a third-party package installed
beside agv-mission works through its entry points (a broken one harms no other mission)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import warnings
from importlib.metadata import entry_points
from pathlib import Path
from typing import Literal

import numpy as np
import pytest

from agv_mission.plugin_check import PluginCheckError, check_plugin
from agv_mission.registry import ENTRY_POINT_GROUP, PluginConfig, PluginWarning, Registry, registry

FIXTURE = Path(__file__).parent / "fixtures" / "straight_line_plugin"
BIN = Path(sys.executable).parent

# The entry points agv-mission itself announces (tests may register more in-process).
BUILTINS = sorted(
    tuple(ep.name.split(".", 1))
    for ep in entry_points(group=ENTRY_POINT_GROUP)
    if ep.dist is not None and ep.dist.name == "agv-mission"
)


def test_the_builtins_are_entry_points() -> None:
    assert {f"{s}.{n}" for s, n in BUILTINS} >= {
        "localization.amcl",
        "localization.ground_truth",
        "localization.odometry",
        "slam.grid",
        "global_planner.ompl",
        "global_planner.grid_astar",
        "global_planner.cost_grid",
        "local_planner.mpc",
        "local_planner.pure_pursuit",
    }


@pytest.mark.parametrize(("slot", "name"), BUILTINS, ids=[f"{s}.{n}" for s, n in BUILTINS])
def test_every_builtin_plugin_passes_check_plugin(slot: str, name: str) -> None:
    cls = registry.get(slot, name)
    assert cls.Config is registry.config(slot, name)
    check_plugin(cls, slot)


class _HalfPlanner:
    """A global planner that forgot half its contract."""

    class Config(PluginConfig):
        type: Literal["half"] = "half"

    def __init__(self, config: Config) -> None:
        self.config = config

    def plan(self, costmap, start, goal) -> np.ndarray:  # no seed, wrong return type
        return np.zeros((2, 2))


class _DriftingLocalizer:
    """Wanders off while the robot stands still."""

    class Config(PluginConfig):
        type: Literal["drift"] = "drift"

    def __init__(self, config: Config, grid, rng) -> None:
        self.x = 0.0

    def reset(self, pose, odom) -> None:
        self.x = pose.x

    def update(self, odom, scan, truth, time):
        from agv_mission.geometry import Pose2D

        self.x += 1.0
        return Pose2D(self.x, truth.y, truth.yaw)

    def request_nomotion_update(self) -> None:
        pass

    def diagnostics(self):
        from agv_mission.localization.base import LocalizerDiagnostics

        return LocalizerDiagnostics()


def test_check_plugin_names_what_is_wrong() -> None:
    with pytest.raises(PluginCheckError) as info:
        check_plugin(_HalfPlanner)
    text = str(info.value)
    assert "global_planner" in text and "missing clearance" in text
    assert "missing diagnostics" in text and "expected parameters" in text
    with pytest.raises(PluginCheckError, match="estimate left a robot standing still"):
        check_plugin(_DriftingLocalizer)


def test_a_name_registered_twice_warns() -> None:
    reg = Registry()
    reg.register("localization", "drift")(_DriftingLocalizer)
    with pytest.warns(PluginWarning, match="registered twice"):
        reg.register("localization", "drift")(_DriftingLocalizer)
    assert reg.get("localization", "drift") is _DriftingLocalizer


def test_schema_and_validate_import_no_mujoco_casadi_or_matplotlib(tmp_path: Path) -> None:
    code = textwrap.dedent(
        """
        import sys
        from agv_mission.cli import main, app
        from typer.main import get_command
        heavy = ("mujoco", "casadi", "matplotlib")
        assert not [m for m in heavy if m in sys.modules], "cli import"
        command = get_command(app)
        command.main(["schema"], standalone_mode=False)
        command.main(["validate", *sys.argv[1:]], standalone_mode=False)
        print("LOADED", [m for m in heavy if m in sys.modules])
        """
    )
    missions = sorted(str(p) for p in (Path(__file__).parents[1] / "missions").glob("*.yaml"))
    proc = subprocess.run(
        [sys.executable, "-c", code, *missions], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.count(": valid") == len(missions) >= 3
    assert "LOADED []" in proc.stdout, proc.stdout[-500:]


@pytest.fixture(scope="module")
def plugin_path(tmp_path_factory) -> str:
    """The fixture package installed the way an editable install does it: setuptools
    builds its metadata (``egg_info``, entry points included) into a directory that goes
    on the path beside the package's source. No wheel tooling needed, nothing faked:
    ``importlib.metadata`` finds the entry points as for any installed package."""
    target = tmp_path_factory.mktemp("site")
    subprocess.run(
        [sys.executable, "-c", "import setuptools; setuptools.setup()"]
        + ["--quiet", "egg_info", "--egg-base", str(target)],
        check=True,
        timeout=120,
        cwd=FIXTURE,
    )
    [entry_points] = target.glob("agv_straight_line.egg-info/entry_points.txt")
    assert "global_planner.straight_line" in entry_points.read_text()
    return os.pathsep.join([str(target), str(FIXTURE / "src")])


MISSION = """\
name: straight
world: turtlebot3_world
start: {x: -2.0, y: -0.5, yaw: 1.5708}
seed: 1
stack:
  localization: {type: ground_truth}
  global_planner: {type: straight_line, step: 0.02}
  local_planner: {type: pure_pursuit}
tasks:
  - type: go_to
    pose: {x: -2.0, y: 0.5, yaw: 1.5708}
limits: {time: 30}
"""


def _cli(args: list[str], plugin_path: str, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": plugin_path}
    return subprocess.run(
        [str(BIN / "agv-mission"), *args],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        cwd=cwd,
    )


def test_an_installed_third_party_plugin_runs_a_mission(plugin_path: str, tmp_path: Path) -> None:
    mission = tmp_path / "straight.yaml"
    mission.write_text(MISSION)
    proc = _cli(["validate", str(mission)], plugin_path, tmp_path)
    assert proc.returncode == 0, proc.stderr
    # the broken plugin of the same package is reported, and harms no one
    assert "local_planner plugin 'broken'" in proc.stderr and "failed to load" in proc.stderr

    proc = _cli(["run", str(mission), "--output", str(tmp_path / "runs")], plugin_path, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    [result] = (tmp_path / "runs").glob("straight-*/result.json")
    assert '"status": "succeeded"' in result.read_text()

    code = (
        "from agv_straight_line import StraightLinePlanner\n"
        "from agv_mission.plugin_check import check_plugin\n"
        "check_plugin(StraightLinePlanner); print('conforms')"
    )
    env = {**os.environ, "PYTHONPATH": plugin_path}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.stdout.strip() == "conforms", proc.stderr


def test_a_mission_naming_the_broken_plugin_is_invalid(plugin_path: str, tmp_path: Path) -> None:
    mission = tmp_path / "broken.yaml"
    mission.write_text(MISSION.replace("{type: pure_pursuit}", "{type: broken}"))
    proc = _cli(["validate", str(mission)], plugin_path, tmp_path)
    assert proc.returncode == 2
    assert "stack.local_planner" in proc.stderr
    assert "'broken' is installed but failed to load" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_without_the_package_its_plugin_is_unknown() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no broken plugin in this process's registry
        assert "straight_line" not in registry.names("global_planner")
