"""The robot's map is not the world: ``map:`` (a map from an earlier SLAM run, furniture
moved since) with the realistic default sensors, and localisation that never does worse
than odometry where scans see little.

Whole missions on the real stack (MuJoCo lidar and encoders, amcl with the scan-to-map
refinement, planner, MPC); the SLAM map in ``tests/fixtures/maps`` was saved by a
``map_area`` run of the small house (seed 1, the default sensors:
``tests/fixtures/maps/make_small_house_slam.py`` makes it again).
"""

from __future__ import annotations

import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from agv_mission.maps.ros_map import save_ros_map
from agv_mission.maps.world_loader import load_world
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.metrics import SETTLE_TIME
from agv_mission.missions.run.runner import MissionRun
from cli_in_process import agv

HERE = Path(__file__).resolve().parent
SLAM_MAP = HERE / "fixtures" / "maps" / "small_house_slam.yaml"
DEPOT = HERE / "worlds" / "loc_depot.yaml"

MISSION = """
name: map-not-world
world: {world}
{map}start: {start}
seed: 3
stack:
  localization: {{type: amcl}}
  global_planner: {{type: grid_astar}}
  local_planner: {{type: mpc}}
tasks:
  - type: patrol
    waypoints: [{waypoints}]
limits: {{time: {limit}}}
{extra}"""

HOUSE_START = "{x: 3.83, y: -1.23, yaw: 0.0}"
HOUSE_ROUTE = "{x: 6.5, y: -2.0, yaw: 0.0}, {x: 4.0, y: 0.5, yaw: 3.14}"
# A box on the map that the world lacks (moved away since mapping), on the straight line
# between the start and the first waypoint.
GONE = (5.2, -1.6, 0.5, 0.5)
# Boxes in the world that the map lacks (moved in since mapping), in the lidar's view.
ADDED = """obstacles:
  - {type: box, x: 4.5, y: 2.0, size_x: 0.5, size_y: 0.8}
  - {type: box, x: 7.5, y: -0.8, size_x: 0.4, size_y: 0.4}
"""


def mission(tmp_path: Path, text: str, name: str = "m.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def house_map_with(box: tuple[float, float, float, float], out: Path) -> Path:
    """The small house's own map with one more box drawn in (map_server files in ``out``)."""
    grid = load_world("small_house").map
    data = np.array(grid.data, copy=True)
    ys, xs = np.mgrid[0 : grid.height, 0 : grid.width]
    cx = grid.origin.x + (xs + 0.5) * grid.resolution
    cy = grid.origin.y + (ys + 0.5) * grid.resolution
    x, y, sx, sy = box
    data[(np.abs(cx - x) <= sx / 2) & (np.abs(cy - y) <= sy / 2)] = 100
    moved = type(grid)(data=data, resolution=grid.resolution, origin=grid.origin)
    return save_ros_map(moved, out / "house_moved")[1]


def run_with_odometry(path: Path) -> tuple[MissionRun, dict[str, float], list[tuple]]:
    """Run the mission; the localisation and odometry-alone errors after SETTLE_TIME, and
    per scan (time, error, x and y sd of the reported covariance)."""
    run = MissionRun(load_mission(path), None)
    update, start, first = run.localizer.update, run.loaded.start, []
    errors: list[tuple[float, float]] = []
    scans: list[tuple[float, float, float, float]] = []

    def observed(odom, scan, truth, now):  # noqa: ANN001, ANN202 - the Localizer signature
        first.append(odom) if not first else None
        dead = start.compose(odom.relative_to(first[0]))
        est = update(odom, scan, truth, now)
        err = math.hypot(est.x - truth.x, est.y - truth.y)
        if now >= SETTLE_TIME:
            errors.append((err, math.hypot(dead.x - truth.x, dead.y - truth.y)))
        if scan is not None:
            cov = run.localizer.covariance
            scans.append((now, err, math.sqrt(cov[0, 0]), math.sqrt(cov[1, 1])))
        return est

    run.localizer.update = observed
    while run.step():
        pass
    e = np.array(errors)
    stats = {
        "rmse": float(np.sqrt(np.mean(e[:, 0] ** 2))),
        "max": float(e[:, 0].max()),
        "odom_rmse": float(np.sqrt(np.mean(e[:, 1] ** 2))),
    }
    return run, stats, scans


def test_map_key_names_file_line_and_field(tmp_path: Path) -> None:
    text = MISSION.format(
        world="small_house",
        map="map: maps/missing.yaml\n",
        start=HOUSE_START,
        waypoints=HOUSE_ROUTE,
        limit=60,
        extra="",
    )
    path = mission(tmp_path, text)
    with pytest.raises(MissionError) as err:
        load_mission(path)
    (problem,) = err.value.problems
    assert problem.field == "map" and problem.file == str(path)
    assert problem.line == text.splitlines().index("map: maps/missing.yaml") + 1
    assert "missing.yaml" in problem.message
    (tmp_path / "bad.yaml").write_text("image: nowhere.pgm\nresolution: -1\n")
    bad = mission(tmp_path, text.replace("maps/missing.yaml", "bad.yaml"), "bad_map.yaml")
    out = validate(bad)
    assert out.returncode == 2 and "Traceback" not in out.stderr + out.stdout
    assert "bad_map.yaml" in out.stdout + out.stderr and "map" in out.stdout + out.stderr
    good = mission(tmp_path, text.replace("maps/missing.yaml", str(SLAM_MAP)), "good.yaml")
    assert validate(good).returncode == 0


def validate(path: Path) -> subprocess.CompletedProcess:
    """``agv-mission validate`` called in this process (test_cli.py starts the program)."""
    return agv("validate", str(path))


def test_the_robot_plans_and_localises_on_its_map_not_the_world(tmp_path: Path) -> None:
    """Furniture moved: a box on the map the world lacks, boxes in the world the map lacks."""
    moved = house_map_with(GONE, tmp_path)
    text = MISSION.format(
        world="small_house",
        map="map: house_moved.yaml\n",  # relative to the mission file
        start=HOUSE_START,
        waypoints=HOUSE_ROUTE,
        limit=120,
        extra=ADDED,
    )
    # Odometry from the wheels alone, as before the robots had an IMU: the gyro-fused one
    # keeps this two-minute run within a centimetre, as close as this map lets amcl come
    # (tests/test_imu.py and benchmarks/bench_imu.py measure the localiser against it).
    text = text.replace(
        "  local_planner: {type: mpc}\n", "  local_planner: {type: mpc}\n  odometry: {imu: false}\n"
    )
    path = mission(tmp_path, text)
    loaded = load_mission(path)
    assert loaded.map is loaded.given_map and moved.is_file()
    box = np.array([[GONE[0], GONE[1]]])
    assert loaded.world.map.value_at(box)[0] == 0  # the world has no box there
    assert not loaded.costmap.is_free(box, 0.0)[0]  # but the robot plans around it
    assert loaded.resolved()["map"] == "house_moved.yaml"
    run, stats, _ = run_with_odometry(path)
    record = run.record()
    assert record.status == "succeeded", record.reason
    assert stats["rmse"] <= 0.03 and stats["max"] <= 0.10, stats
    assert record.metrics["localization"]["consistency_2sigma"] >= 0.9
    assert stats["rmse"] < stats["odom_rmse"]


def test_a_slam_map_from_an_earlier_map_area_run(tmp_path: Path) -> None:
    text = MISSION.format(
        world="small_house",
        map=f"map: {SLAM_MAP}\n",
        start=HOUSE_START,
        waypoints=HOUSE_ROUTE,
        limit=120,
        extra="",
    )
    # against the wheels' odometry, as before the IMU (see the test above)
    text = text.replace(
        "  local_planner: {type: mpc}\n", "  local_planner: {type: mpc}\n  odometry: {imu: false}\n"
    )
    run, stats, _ = run_with_odometry(mission(tmp_path, text))
    record = run.record()
    assert record.status == "succeeded", record.reason
    # The SLAM map itself is a few centimetres off the world (its run's own trajectory
    # error was 0.030 m RMSE): the estimate is as good as the map. Measured: 0.027 m RMSE,
    # 0.041 m max; on the map saved while map_area drifted (0.09 m), 0.070 / 0.116 m.
    assert stats["rmse"] <= 0.045 and stats["max"] <= 0.10, stats
    assert stats["rmse"] < stats["odom_rmse"]


HALL = """name: open_hall
resolution: 0.05
bounds: {xmin: -0.5, xmax: 30.5, ymin: -6.5, ymax: 6.5}
spawn: {x: 1.0, y: 0.0, yaw: 0.0}
boxes:
- {x: 15.0, y: -6.1, size: [30.4, 0.2]}
- {x: 15.0, y: 6.1, size: [30.4, 0.2]}
- {x: -0.1, y: 0.0, size: [0.2, 12.0]}
- {x: 30.1, y: 0.0, size: [0.2, 12.0]}
"""


def test_open_hall_never_worse_than_odometry_and_says_so(tmp_path: Path) -> None:
    """Down the middle of a 30 x 12 m hall (its side walls 6 m away, beyond the LDS-01's
    3.5 m): where the lidar sees nothing the estimate follows odometry, no worse than dead
    reckoning, and its covariance grows along the hall, where the end wall had pinned it (a
    single wall never pins the other direction: that one stays as wide as the start's)."""
    (tmp_path / "hall.yaml").write_text(HALL)
    text = MISSION.format(
        world="hall.yaml",
        map="",
        start="{x: 1.0, y: 0.0, yaw: 0.0}",
        waypoints="{x: 12.0, y: 0.0, yaw: 0.0}",
        limit=150,
        extra="",
    )
    # against the wheels' odometry, as before the IMU: the gyro-fused one ends this hall
    # ~2 cm off, and amcl ~3 cm (the last scans of the start wall, at the lidar's range,
    # tilt its heading by ~5 mrad; docs/imu-and-localisation.md)
    text = text.replace(
        "  local_planner: {type: mpc}\n", "  local_planner: {type: mpc}\n  odometry: {imu: false}\n"
    )
    run, stats, scans = run_with_odometry(mission(tmp_path, text))
    record = run.record()
    assert record.status == "succeeded", record.reason
    assert stats["rmse"] <= stats["odom_rmse"] + 1e-3, stats
    t, err, sd_x, sd_y = np.array(scans).T
    assert sd_x[-1] > 3.0 * sd_x[t < 2.0].max()  # blind: a wider ellipse, not a false fix
    assert sd_y.min() > 0.3  # the start's 0.5 m: nothing ever saw y
    assert np.mean(err <= 2.0 * np.hypot(sd_x, sd_y)) >= 0.9  # the truth inside it
