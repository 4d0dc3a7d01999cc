"""regress on Ctrl-C: queued runs cancelled, running ones aborted, reports of what ran."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

LONG = """\
name: long-{i}
world: turtlebot3_world
robot: burger
start: {{x: -2.0, y: -0.5, yaw: 0.0}}
stack: {{localization: {{type: ground_truth}}}}
tasks:
  - type: patrol
    waypoints: [{{x: -1.6, y: -0.5, yaw: 0.0}}, {{x: -2.0, y: -0.5, yaw: 3.14}}]
    loops: 1000000
limits: {{time: 900.0}}
expect: {{status: failed}}
"""


def test_ctrl_c_cancels_queued_runs_and_reports_what_ran(tmp_path: Path) -> None:
    suite = tmp_path / "suite"
    suite.mkdir()
    for i in range(5):
        (suite / f"long_{i}.yaml").write_text(LONG.format(i=i))
    out, junit, summary = tmp_path / "out", tmp_path / "junit.xml", tmp_path / "summary.json"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "agv_mission.cli",
            "regress",
            str(suite),
            "-j",
            "2",
            "--output",
            str(out),
            "--junit",
            str(junit),
            "--json",
            str(summary),
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:  # wait until two runs are under way
        if out.exists() and len([p for p in out.iterdir() if (p / "mission.yaml").exists()]) >= 2:
            break
        time.sleep(0.2)
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)  # to the parent only, as `kill -INT` does
    stdout, stderr = proc.communicate(timeout=180)
    assert proc.returncode == 130, stdout + stderr
    assert "Traceback" not in stderr
    run_dirs = sorted(out.iterdir())
    assert len(run_dirs) == 2  # the three queued scenarios never started
    for run_dir in run_dirs:
        result = json.loads((run_dir / "result.json").read_text())
        assert result["status"] == "aborted"
    doc = json.loads(summary.read_text())
    assert len(doc["runs"]) == 2
    assert {r["status"] for r in doc["runs"]} == {"aborted"}
    cases = ET.parse(junit).getroot().iter("testcase")
    assert len(list(cases)) == 2
