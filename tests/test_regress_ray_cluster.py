"""regress --backend ray --address: the scenario files travel to the cluster (Ray's
runtime_env working_dir) and the run directories come back. Against a real local Ray
cluster (``ray start --head``) started here in its own working directory."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

SCENARIO = """\
name: go
world: arena.world.yaml             # a file next to the scenario: it must travel too
start: {x: 0.0, y: 0.0, yaw: 0.0}
stack: {localization: {type: ground_truth}}
tasks:
  - {type: go_to, pose: {x: 0.5, y: 0.0, yaw: 0.0}}
limits: {time: 30.0}
expect: {status: succeeded}
"""
ARENA = Path(__file__).resolve().parent / "invalid" / "data" / "arena.world.yaml"
RAY = Path(sys.executable).parent / "ray"
ENV = {**os.environ, "RAY_AUTH_MODE": "disabled"}  # a throwaway cluster on loopback


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def ray_cluster() -> Iterator[str]:
    """A one-node cluster in a scratch folder (short: Ray's socket paths are limited);
    stopped by killing its own process group, never `ray stop` (other clusters live)."""
    scratch = Path(tempfile.mkdtemp(prefix="rayt", dir="/tmp"))
    port = _free_port()
    head = subprocess.Popen(
        [
            str(RAY),
            "start",
            "--head",
            f"--port={port}",
            "--node-ip-address=127.0.0.1",
            "--num-cpus=2",
            "--include-dashboard=false",
            "--disable-usage-stats",
            f"--temp-dir={scratch / 'tmp'}",
            "--block",
        ],
        cwd=scratch,
        env=ENV,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and not list((scratch / "tmp").glob("session_*")):
            time.sleep(0.5)
        time.sleep(5.0)  # the raylet registers after the session folder appears
        yield f"127.0.0.1:{port}"
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        try:
            head.wait(timeout=10)
        except subprocess.TimeoutExpired:
            os.killpg(head.pid, signal.SIGKILL)
        shutil.rmtree(scratch, ignore_errors=True)
        # a killed head leaves its address for ray.init() to find: not ours to leave
        current = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"
        if current.is_file() and current.read_text().strip().endswith(f":{port}"):
            current.unlink()


@pytest.mark.slow
def test_ray_cluster_gets_the_scenario_files_and_returns_the_runs(
    tmp_path: Path, ray_cluster: str
) -> None:
    suite = tmp_path / "suite"
    suite.mkdir()
    (suite / "go.yaml").write_text(SCENARIO)
    shutil.copy(ARENA, suite / "arena.world.yaml")
    client = tmp_path / "client"  # not the suite's folder: paths must not leak through
    client.mkdir()
    r = subprocess.run(
        [
            sys.executable,
            "-m",
            "agv_mission.cli",
            "regress",
            str(suite),
            "--backend",
            "ray",
            "--address",
            ray_cluster,
            "--output",
            "out",
            "--json",
            "summary.json",
        ],
        cwd=client,
        env=ENV,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stdout + r.stderr
    [result] = json.loads((client / "summary.json").read_text())["runs"]
    assert result["status"] == "succeeded" and result["passed"]
    run_dir = Path(result["run_dir"])
    assert run_dir.parent == (client / "out").resolve()
    assert {"result.json", "trajectory.csv", "mission.yaml", "run.png"} <= {
        p.name for p in run_dir.iterdir()
    }
    assert json.loads((run_dir / "result.json").read_text())["world"] == "invalid_arena"
