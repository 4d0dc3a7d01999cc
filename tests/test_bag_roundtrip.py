"""Round trip: a run's bag, mapped offline by `agv-mission map`, reproduces the map that
`map_area` built live in the same run (free-cell IoU against the world)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from agv_mission.bags.writer import BagWriter
from agv_mission.cli import app
from agv_mission.mapping.quality import map_quality, reference_agreement
from agv_mission.maps.ros_map import load_ros_map
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import run_mission

REPO = Path(__file__).resolve().parents[1]


def _round_trip(tmp_path: Path, mission: Path | str, overrides: list[str], text: str | None = None):
    loaded = (
        load_mission(mission, overrides, text=text) if text else load_mission(mission, overrides)
    )
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    write_run(run_dir, loaded, record)
    assert record.status == "succeeded", record.reason
    live = record.extras["maps"][0]
    result = CliRunner().invoke(
        app, ["map", str(run_dir / "bag"), "--save-map", str(tmp_path / "offline")]
    )
    assert result.exit_code == 0, result.output
    offline = load_ros_map(tmp_path / "offline.yaml")
    start = (loaded.start.x, loaded.start.y)
    quality = map_quality(offline, loaded.world.map, None, start)
    report = json.loads((tmp_path / "offline_report.json").read_text())
    return live, quality, report, loaded, run_dir / "bag"


@pytest.mark.slow  # 16 s; the fast suite maps a run's bag in test_mission_matrix and test_bag_mapping
def test_round_trip_turtlebot3_world(tmp_path):
    live, quality, report, loaded, bag = _round_trip(
        tmp_path, REPO / "tests" / "scenarios" / "map_area_tb3.yaml", []
    )
    # `map` calls no cell FREE that ever returned a beam (free_max_hits: 0), the LDS-01's
    # noisy band along the walls included: fewer free cells, each more surely free.
    assert quality["free_iou"] >= 0.9, quality
    plain = CliRunner().invoke(
        app,
        ["map", str(bag), "--set", "free_max_hits=null"] + ["--save-map", str(tmp_path / "plain")],
    )
    world = loaded.world.map
    plain_map = load_ros_map(tmp_path / "plain.yaml")
    offline_map = load_ros_map(tmp_path / "offline.yaml")
    careful = reference_agreement(offline_map, world)["free_in_reference"]
    assert careful >= reference_agreement(plain_map, world)["free_in_reference"]
    # Without it the offline map is the live one. It is anchored at the bag's map -> odom at
    # the first scan: amcl's first cluster mean, a few cm off the start, so the two maps
    # differ by that shift.
    assert plain.exit_code == 0, plain.output
    plain_quality = map_quality(plain_map, world, None, (loaded.start.x, loaded.start.y))
    assert plain_quality["free_iou"] >= live["free_iou"] - 0.03, (plain_quality, live)
    assert report["rmse"]["ate_aligned"] < 0.02  # realistic sensors: 0.011 (ideal: < 0.01)
    assert report["scans"]["used"] == report["scans"]["total"]
    assert report["rmse"]["position_rmse"] < 0.05


@pytest.mark.slow
def test_round_trip_aws_small_house_patrol(tmp_path):
    """A patrol through every room of the real AWS small-house map, mapped from its bag."""
    loaded = load_mission(REPO / "benchmarks" / "data" / "house_patrol.yaml")
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    assert record.status == "succeeded", record.reason
    result = CliRunner().invoke(
        app, ["map", str(run_dir / "bag"), "--save-map", str(tmp_path / "m")]
    )
    assert result.exit_code == 0, result.output
    offline = load_ros_map(tmp_path / "m.yaml")
    quality = map_quality(offline, loaded.world.map, None, (loaded.start.x, loaded.start.y))
    # Realistic sensors, seeds 1-4: free IoU 0.913-0.946, the trajectory's shape (ATE)
    # 0.03-0.06 m, when the map's frame was the first scan's estimate: SLAM's early heading
    # turned the whole map by up to a degree (its far walls centimetres off). Fitted to the
    # robot's estimate over the run (seed 4: IoU 0.919 -> 0.949, RMSE 0.120 -> 0.045 m)
    # the map's frame adds nothing to its shape's error.
    assert quality["free_iou"] >= 0.93, quality
    report = json.loads((tmp_path / "m_report.json").read_text())
    assert report["map_frame"]["fitted"] is True
    assert report["rmse"]["ate_aligned"] < 0.07, report["rmse"]
    assert report["rmse"]["position_rmse"] <= report["rmse"]["ate_aligned"] + 0.01
