"""What a command imports before it answers (issue 16: start-up): ``--help`` needs no
numerical library, bad input is reported before the world's machinery (scipy, Pillow,
lxml) is imported, and validating a good file never imports the simulator, the
controller, the plotting or the behaviour-tree runtime (nor scipy.ndimage and OMPL once
what they give is stored). Each case runs the real commands in a fresh interpreter and
lists the heavy packages it loaded; nothing is timed."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MISSIONS = sorted(str(p) for p in (ROOT / "missions").glob("*.yaml"))

# Runs each argument list (JSON) as ``agv-mission ...`` in this one process, then prints
# the exit codes and which of the watched packages are loaded.
PROGRAM = textwrap.dedent(
    """
    import json, sys
    from typer.main import get_command
    from agv_mission.cli import app
    command = get_command(app)
    codes = []
    for args in json.loads(sys.argv[1]):
        try:
            codes.append(command.main(args, standalone_mode=False, prog_name="agv-mission"))
        except SystemExit as exc:  # --help exits itself
            codes.append(exc.code)
    loaded = sorted(m for m in json.loads(sys.argv[2]) if m in sys.modules)
    print("RESULT", json.dumps({"codes": codes, "loaded": loaded}))
    """
)

SIMULATION = ["mujoco", "casadi", "matplotlib", "glfw", "py_trees", "mcap", "rosbags"]
WORLD = ["scipy", "PIL", "lxml", "contourpy", "ompl", *SIMULATION]
NUMERICAL = ["numpy", "pydantic", "shapely", *WORLD]


def commands(runs: list[list[str]], watched: list[str], env: dict | None = None) -> dict:
    proc = subprocess.run(
        [sys.executable, "-c", PROGRAM, json.dumps(runs), json.dumps(watched)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
        env=env,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    [line] = [x for x in proc.stdout.splitlines() if x.startswith("RESULT ")]
    return json.loads(line.removeprefix("RESULT "))


def test_help_imports_no_numerical_library() -> None:
    result = commands([["run", "--help"], ["validate", "--help"]], NUMERICAL)
    assert result == {"codes": [0, 0], "loaded": []}


@pytest.fixture
def bad_files(tmp_path: Path) -> tuple[Path, Path]:
    schema_error = tmp_path / "schema_error.yaml"
    schema_error.write_text(
        "world: turtlebot3_world\ntasks:\n  - type: go_to\n    pose: {x: 1.0, y: nope}\n"
    )
    not_yaml = tmp_path / "not_yaml.yaml"
    not_yaml.write_text("tasks: [unclosed\n")
    return schema_error, not_yaml


def test_bad_input_is_reported_before_the_world_is_imported(
    bad_files: tuple[Path, Path], tmp_path: Path
) -> None:
    schema_error, not_yaml = bad_files
    runs = [
        ["validate", str(schema_error)],
        ["validate", str(not_yaml)],
        ["run", str(tmp_path / "missing.yaml")],
        ["run", str(schema_error), "--output", str(tmp_path / "runs")],
    ]
    result = commands(runs, WORLD)
    assert result == {"codes": [2, 2, 2, 2], "loaded": []}
    assert not (tmp_path / "runs").exists()


@pytest.fixture(scope="module")
def validated() -> dict:
    """``validate`` of every shipped mission in one fresh interpreter, watching the
    simulation's packages and scipy.sparse (each test below asserts on its own part)."""
    return commands([["validate", *MISSIONS]], [*SIMULATION, "scipy.sparse"])


def test_validate_imports_no_simulator_controller_or_plotting(validated: dict) -> None:
    assert len(MISSIONS) >= 3
    assert validated["codes"] == [0]
    assert [m for m in validated["loaded"] if m in SIMULATION] == []


def test_validate_without_people_imports_no_sparse_graphs(validated: dict) -> None:
    """People's walking routes are a scipy.sparse graph (~0.1 s to import): a mission
    without people is validated without it."""
    assert not any("people:" in Path(m).read_text() for m in MISSIONS)
    assert validated["codes"] == [0]
    assert "scipy.sparse" not in validated["loaded"]


def test_validate_reads_stored_tables_instead_of_importing_scipy_or_ompl(tmp_path: Path) -> None:
    """The worlds' free space and distance fields need scipy.ndimage to build, the list of
    OMPL's planners OMPL's libraries (each ~0.1-0.5 s to import): the first process stores
    them, a later one validates without either."""
    env = {**os.environ, "AGV_MISSION_STORE": str(tmp_path / "stored")}
    first = commands([["validate", *MISSIONS]], ["scipy.ndimage", "ompl"], env)
    assert first == {"codes": [0], "loaded": ["ompl", "scipy.ndimage"]}
    for kind in ("spawn_region-*.npy", "obstacle_distance-*.npy", "ompl_planners-*.json"):
        assert list((tmp_path / "stored").glob(kind))
    again = commands([["validate", *MISSIONS]], ["scipy.ndimage", "ompl"], env)
    assert again == {"codes": [0], "loaded": []}
