"""The command line as a user meets it: exit codes and messages, never a traceback."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXE = [sys.executable, "-m", "agv_mission.cli"]


def cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*EXE, *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def run_text(tmp_path: Path, name: str, text: str) -> tuple[subprocess.CompletedProcess, Path]:
    """``agv-mission run`` on a mission written from ``text``; the process and the output
    root (``tmp_path / "out"``)."""
    mission = tmp_path / f"{name}.yaml"
    mission.write_text(text)
    out = tmp_path / "out"
    return cli("run", str(mission), "--output", str(out)), out


def test_validate_demo_ok() -> None:
    r = cli("validate", str(REPO / "missions" / "patrol.yaml"))
    assert r.returncode == 0, r.stderr


def test_validate_invalid_exits_2_with_line_and_field(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("tasks:\n  - type: go_to\n    pose: {x: 0.5, y: -0.5}\n    colour: red\n")
    r = cli("validate", str(bad))
    assert r.returncode == 2
    assert f"{bad}:4: tasks.0.colour" in r.stderr
    assert "Traceback" not in r.stderr + r.stdout


def test_run_invalid_and_missing_file_exit_2(tmp_path: Path) -> None:
    r = cli("run", str(tmp_path / "nope.yaml"))
    assert r.returncode == 2 and "cannot read" in r.stderr and "Traceback" not in r.stderr
    r = cli(
        "run", str(REPO / "missions" / "patrol.yaml"), "--set", "stack.global_planner.planner=Nope"
    )
    assert r.returncode == 2 and "Nope" in r.stderr and "Traceback" not in r.stderr


def test_schema_is_json_with_the_contract_keys() -> None:
    r = cli("schema")
    assert r.returncode == 0
    schema = json.loads(r.stdout)
    contract = "name world rooms robot start seed stack tasks limits output"  # mission-format.md
    assert set(contract.split()) <= set(schema["properties"])


def test_run_writes_a_complete_run_directory(tmp_path: Path) -> None:
    r, out = run_text(
        tmp_path,
        "short",
        "name: short\nworld: turtlebot3_world\nstart: {x: -2.0, y: -0.5, yaw: 0}\n"
        "tasks: [{type: go_to, pose: {x: -1.6, y: -0.5, yaw: 0.5}}]\nlimits: {time: 60}\n",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    [run_dir] = out.iterdir()
    assert run_dir.name.startswith("short-")
    for name in ("result.json", "trajectory.csv", "mission.yaml", "run.png", "tree.txt"):
        assert (run_dir / name).stat().st_size > 0, name
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "succeeded" and result["reason"] is None
    assert result["tasks"][0]["status"] == "succeeded"
    header = (run_dir / "trajectory.csv").read_text().splitlines()[0]
    # The contract's nine columns, the estimate's covariance (amcl reports one), then the
    # battery's level (the burger has one), last.
    assert header == ("t,x,y,yaw,est_x,est_y,est_yaw,v,w,cov_xx,cov_xy,cov_yy,cov_yawyaw,battery")
    last = (run_dir / "trajectory.csv").read_text().splitlines()[-1].split(",")
    battery = result["metrics"]["battery"]
    assert float(last[-1]) == pytest.approx(battery["end"], abs=1e-5)
    assert 0.99 < battery["end"] < battery["start"] == 1.0
    # the leg table: planned, shortest and driven length and the two ratios
    [leg] = result["metrics"]["navigation"]["legs"]
    assert "/shortest" in r.stdout and "shortest m" in r.stdout
    row = f"-1.60,-0.50 succeeded {leg['planned']:.2f} {leg['shortest']:.2f} {leg['driven']:.2f}"
    assert row in " ".join(r.stdout.split()), r.stdout
    nav = result["metrics"]["navigation"]
    assert nav["planned_length"] == leg["planned"] and nav["shortest_length"] == leg["shortest"]
    assert "path_length_total" not in nav


def test_failed_mission_exits_1_with_reason(tmp_path: Path) -> None:
    r, out = run_text(
        tmp_path,
        "late",
        "world: turtlebot3_world\nstart: {x: -2.0, y: -0.5, yaw: 0}\n"
        "tasks: [{type: go_to, pose: {x: 1.13, y: -1.6}}]\nlimits: {time: 3}\n",
    )
    assert r.returncode == 1
    [run_dir] = out.iterdir()
    result = json.loads((run_dir / "result.json").read_text())
    assert result["status"] == "failed" and "time limit" in result["reason"]


def test_summary_counts_rooms_and_recordings(tmp_path: Path) -> None:
    r, _ = run_text(
        tmp_path,
        "rooms",
        "world: small_house\nstart: livingroom\nstack: {localization: {type: ground_truth}}\n"
        "tasks: [{type: visit_rooms, rooms: [livingroom], record: true, settle: 0}]\n",
    )
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1/1 rooms reached, 1 recorded" in r.stdout
