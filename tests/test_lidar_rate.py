"""A lidar faster than the 10 Hz control loop: every scan at its own time stamp reaches the
localiser, the obstacle layer, the observers and the bag's /scan."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from agv_mission.bags.writer import BagWriter
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import MissionRun, run_mission
from agv_mission.missions.run.stack import CONTROL_PERIOD

ROBOT = """\
wheel_radius: 0.033
wheel_separation: 0.16
footprint_radius: 0.105
max_linear_velocity: 0.22
max_angular_velocity: 2.84
encoder: {{ticks_per_meter: 19754.0}}
lidar: {{beams: 90, range_min: 0.12, range_max: 3.5, rate: {rate}, height: 0.17}}
"""
MISSION = """\
name: fast-lidar
world: turtlebot3_world
robot: fast.robot.yaml
start: {x: -2.0, y: -0.5, yaw: 0.0}
seed: 4
stack:
  localization:
    type: amcl
    update_min_d: 0.0
    update_min_a: 0.0
    min_particles: 100
    max_particles: 200
tasks: [{type: go_to, pose: {x: -1.4, y: -0.5, yaw: 0.0}}]
limits: {time: 2.0}
"""


class _Scans:
    """Keeps every scan each step hands the observers."""

    def __init__(self) -> None:
        self.stamps: list[float] = []

    def on_start(self, start) -> None:
        pass

    def on_step(self, sample) -> None:
        self.stamps += [float(s.time) for s in sample.scans]
        assert sample.scans[-1:] == ((sample.scan,) if sample.scan is not None else ())

    def on_end(self, record) -> None:
        pass


def _mission(tmp_path: Path, rate: float) -> Path:
    (tmp_path / "fast.robot.yaml").write_text(ROBOT.format(rate=rate))
    path = tmp_path / "fast.yaml"
    path.write_text(MISSION)
    return path


@pytest.mark.parametrize("rate", [25.0, 7.0])
def test_every_scan_at_its_own_time(tmp_path: Path, rate: float) -> None:
    loaded = load_mission(_mission(tmp_path, rate))
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    scans = _Scans()
    record = run_mission(loaded, run_dir, observers=[BagWriter(), scans])
    write_run(run_dir, loaded, record)
    expected = math.floor(record.sim_time * rate + 1e-9) + 1  # one at t = 0
    stamps = np.array(scans.stamps)
    assert len(stamps) == expected
    # at the lidar's own period (to the 10 ms physics step), not the control loop's
    np.testing.assert_allclose(np.diff(stamps), 1.0 / rate, atol=0.0101)
    np.testing.assert_allclose(stamps, np.round(np.arange(expected) / rate, 2), atol=0.0051)
    with AnyReader([run_dir / "bag"]) as reader:
        [conn] = [c for c in reader.connections if c.topic == "/scan"]
        bagged = [reader.deserialize(raw, conn.msgtype) for _, _, raw in reader.messages([conn])]
    bag_stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in bagged]
    np.testing.assert_allclose(bag_stamps, stamps, atol=1e-9)


def test_each_scan_reaches_the_localiser_and_the_obstacle_layer(tmp_path: Path) -> None:
    """Per control step, the localiser and the obstacle layer see each scan taken in it."""
    loaded = load_mission(_mission(tmp_path, 25.0))
    run = MissionRun(loaded, None)
    seen: list[float] = []
    layer_update = run.navigator.layer.update

    def update(pose, scan) -> None:
        seen.append(float(scan.time))
        layer_update(pose, scan)

    run.navigator.layer.update = update  # the real layer, watched
    for _ in range(10):
        run.step()
    # amcl (no motion threshold) updates its filter with every scan
    assert run.localizer.diagnostics().filter_updates == len(seen)
    assert len(seen) == math.floor(9 * CONTROL_PERIOD * 25 + 1e-9) + 1  # sensed by t = 0.9 s
