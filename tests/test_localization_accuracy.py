"""Centimetre localisation: the scan-to-map refinement, then real missions on real maps.

Unit checks drive :class:`PoseTracker` with scans marched through small synthetic grids;
the missions run the whole stack (MuJoCo lidar and encoders, planner, MPC) on the real AWS
small house map_server map and on the 30 x 50 m warehouse and 30 x 15 m depot worlds in
``tests/worlds``, and check position RMSE, maximum error (both after the first 10 s) and
that the true error lies inside the reported 2-sigma ellipse at least 90 % of the steps.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.localization.amcl import AmclConfig, AmclLocalizer
from agv_mission.localization.distance_field import SignedDistanceField
from agv_mission.localization.pose_tracker import PoseTracker, RefineParams, floor_covariance
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import write_run
from agv_mission.missions.run.metrics import COVARIANCE_COLUMNS
from agv_mission.missions.run.record import TRAJECTORY_COLUMNS
from agv_mission.missions.run.runner import run_mission
from agv_mission.sensor_msgs import LaserScan

RES = 0.05
PAD = 10
WORLDS = Path(__file__).resolve().parent / "worlds"


def grid_of(width: float, height: float, boxes=()) -> OccupancyGrid:
    """A walled rectangle (walls 2 cells thick) with extra boxes (xmin, ymin, xmax, ymax),
    inside 10 cells of unknown space (what map_saver shows outside a building)."""
    w, h = round(width / RES), round(height / RES)
    room = np.zeros((h, w), np.int8)
    room[:2, :] = room[-2:, :] = 100
    room[:, :2] = room[:, -2:] = 100
    for x0, y0, x1, y1 in boxes:
        room[round(y0 / RES) : round(y1 / RES), round(x0 / RES) : round(x1 / RES)] = 100
    data = np.full((h + 2 * PAD, w + 2 * PAD), -1, np.int8)
    data[PAD : PAD + h, PAD : PAD + w] = room
    return OccupancyGrid(data, RES, Pose2D(-PAD * RES, -PAD * RES, 0.0))


def scan_points(grid: OccupancyGrid, pose: Pose2D, rng=None, range_max: float = 3.5):
    """Robot-frame end points of a 360-beam scan marched through ``grid`` (1 cm noise)."""
    a = np.arange(360) * 2.0 * math.pi / 360
    steps = np.arange(0.0, range_max, 0.002)
    pts = np.stack(
        [
            pose.x + np.cos(a + pose.yaw)[:, None] * steps,
            pose.y + np.sin(a + pose.yaw)[:, None] * steps,
        ],
        axis=-1,
    )
    occ = grid.value_at(pts) >= 65
    r = steps[occ.argmax(axis=1)]
    ok = occ.any(axis=1) & (r > 0.12)
    if rng is not None:
        r = r + rng.normal(0.0, 0.01, len(r))
    return np.stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])], axis=1)


ROOM = grid_of(6.0, 4.0, boxes=[(1.0, 1.0, 1.6, 1.5), (4.2, 2.6, 4.5, 3.4)])


# --------------------------------------------------------------------------- unit checks


def test_signed_distance_is_zero_on_wall_faces_and_negative_inside():
    sdf = SignedDistanceField(ROOM)
    # The west wall fills x in [0, 0.1): its face is at x = 0.1.
    d, g = sdf.lookup(np.array([[0.1, 2.0], [0.3, 2.0], [0.08, 2.0], [1.3, 0.9]]))
    assert d[0] == pytest.approx(0.0, abs=1e-9)
    assert d[1] == pytest.approx(0.2, abs=1e-9)
    assert d[2] == pytest.approx(-0.02, abs=1e-9)
    assert d[3] == pytest.approx(0.1, abs=1e-9)  # below the box at y = 1.0
    assert g[1] == pytest.approx([1.0, 0.0])  # away from the wall
    d, g = sdf.lookup(np.array([[-5.0, 2.0]]))  # off the map: far, no gradient
    assert d[0] == sdf.max_distance and not g.any()


def test_a_scan_pins_an_offset_prior_to_millimetres():
    truth = Pose2D(3.0, 2.1, 0.4)
    pts = scan_points(ROOM, truth, np.random.default_rng(0))
    tracker = PoseTracker(ROOM)
    prior = np.diag([0.1**2, 0.1**2, 0.1**2])
    tracker.start(truth.as_array() + [0.12, -0.08, 0.06], prior)
    corr = tracker.correct(pts)
    assert corr.accepted and corr.inlier_fraction > 0.95
    assert math.hypot(corr.mean[0] - truth.x, corr.mean[1] - truth.y) < 0.005
    assert abs(corr.mean[2] - truth.yaw) < 0.003
    assert np.all(np.linalg.eigvalsh(tracker.cov) < np.linalg.eigvalsh(prior))
    # Covariance floor: the fit's residual RMS (~1 cm) bounds the x, y sd from below.
    assert math.sqrt(tracker.cov[0, 0]) >= 0.9 * tracker.fit_rms > 0.005


def test_a_corridor_keeps_its_axis_uncertain():
    corridor = grid_of(20.0, 1.6)
    truth = Pose2D(10.0, 0.8, 0.0)
    tracker = PoseTracker(corridor)
    tracker.start(truth.as_array() + [0.15, 0.05, 0.02], np.diag([0.2**2, 0.2**2, 0.05**2]))
    corr = tracker.correct(scan_points(corridor, truth, np.random.default_rng(1)))
    assert corr.accepted
    assert abs(corr.mean[1] - truth.y) < 0.005  # across: pinned
    assert abs(corr.mean[0] - truth.x) > 0.1  # along: the scan cannot tell
    assert math.sqrt(tracker.cov[0, 0]) > 0.15 and math.sqrt(tracker.cov[1, 1]) < 0.02


def test_a_scan_that_does_not_fit_is_rejected():
    truth = Pose2D(3.0, 2.1, 0.4)
    tracker = PoseTracker(ROOM)
    wrong = np.array([1.5, 3.0, -1.0])
    tracker.start(wrong, np.diag([0.02**2, 0.02**2, 0.01**2]))
    corr = tracker.correct(scan_points(ROOM, truth))
    assert not corr.accepted and corr.inlier_fraction < 0.6
    assert np.array_equal(tracker.mean, wrong)  # the state is untouched
    few = tracker.correct(scan_points(ROOM, truth)[:5])
    assert not few.accepted and few.beams == 5


def test_motion_noise_is_a_random_walk_whatever_the_step_size():
    covs = []
    for steps in (1, 10, 100):
        tracker = PoseTracker(ROOM, RefineParams(noise_along=0.02))
        tracker.start(np.zeros(3), np.diag([1e-8] * 3))
        for _ in range(steps):
            tracker.predict(np.array([1.0 / steps, 0.0, 0.0]))
        covs.append(tracker.cov[0, 0])
        assert tracker.mean[0] == pytest.approx(1.0)
    assert covs == pytest.approx([0.02**2 + 1e-8] * 3, rel=1e-9)


def test_covariance_floor_raises_only_small_directions():
    cov = np.diag([1e-6, 0.04, 1e-8])
    out = floor_covariance(cov, np.array([0.01, 0.01, 0.005]))
    assert np.diag(out) == pytest.approx([1e-4, 0.04, 0.005**2])


def drive_room(
    loc: AmclLocalizer, seconds: float, seed: int = 0, scale: float = 1.0, scan_every: int = 2
) -> np.ndarray:
    """Drive circles in ROOM with 2 % odometry noise (distances times ``scale``), a scan
    every ``scan_every`` steps; rows (err_x, err_y, cov_xx, cov_xy, cov_yy)."""
    rng = np.random.default_rng(seed)
    truth, odom = Pose2D(3.0, 2.0, 0.0), Pose2D(0.0, 0.0, 0.0)
    loc.reset(truth, odom)
    rows = []
    for k in range(1, round(seconds / 0.1) + 1):
        v, w = 0.2, 0.25
        truth = truth.compose(Pose2D(v * 0.1, 0.0, w * 0.1))
        noisy = Pose2D(v * 0.1 * scale * (1 + 0.02 * rng.standard_normal()), 0.0, w * 0.1)
        odom = odom.compose(noisy)
        scan = None
        if k % scan_every == 0:
            pts = scan_points(ROOM, truth, rng)
            r = np.full(360, np.inf, np.float32)
            ang = np.round(np.arctan2(pts[:, 1], pts[:, 0]) / (2 * math.pi / 360)).astype(int) % 360
            r[ang] = np.hypot(pts[:, 0], pts[:, 1])
            scan = LaserScan(r, 0.0, 2 * math.pi / 360, 0.12, 3.5, 0.1 * k)
        est = loc.update(odom, scan, Pose2D(-99.0, -99.0, 0.0), 0.1 * k)
        c = loc.covariance
        rows.append((est.x - truth.x, est.y - truth.y, c[0, 0], c[0, 1], c[1, 1]))
    return np.asarray(rows)


def coverage_2sigma(rows: np.ndarray) -> float:
    ex, ey, xx, xy, yy = rows.T
    d2 = (yy * ex**2 - 2 * xy * ex * ey + xx * ey**2) / (xx * yy - xy**2)
    return float(np.mean(d2 <= 4.0))


def test_default_profile_refines_and_its_covariance_is_consistent():
    loc = AmclLocalizer(AmclConfig(), ROOM, np.random.default_rng(2))
    rows = drive_room(loc, 40.0)
    err = np.hypot(rows[:, 0], rows[:, 1])
    assert loc.refining and loc.refine_stats["accepted"] > 150
    assert np.sqrt(np.mean(err[50:] ** 2)) < 0.01
    assert coverage_2sigma(rows) >= 0.9
    # The TurtleBot3 profile is amcl alone: no refinement, several times less accurate.
    tb3 = AmclLocalizer(AmclConfig(profile="turtlebot3"), ROOM, np.random.default_rng(2))
    rows_tb3 = drive_room(tb3, 40.0)
    assert not tb3.refining and tb3.tracker is None
    assert np.sqrt(np.mean(np.hypot(rows_tb3[50:, 0], rows_tb3[50:, 1]) ** 2)) > 0.02


def test_odometry_noise_adapts_to_slipping_wheels():
    # Wheels that report 25 % too much travel, a scan every 2 s: the prediction is off
    # by ~10 cm when each scan arrives, far outside what the configured noise says.
    slipping = AmclLocalizer(AmclConfig(), ROOM, np.random.default_rng(4))
    rows = drive_room(slipping, 60.0, scale=1.25, scan_every=20)
    assert slipping.tracker.noise_scale > 5.0
    assert coverage_2sigma(rows[100:]) >= 0.9  # after the first 10 s (5 scans)
    fixed = AmclLocalizer(AmclConfig(refine_adaptive_noise=False), ROOM, np.random.default_rng(4))
    rows_fixed = drive_room(fixed, 60.0, scale=1.25, scan_every=20)
    assert fixed.tracker.noise_scale == 1.0
    assert coverage_2sigma(rows_fixed[100:]) < 0.5


# --------------------------------------------------------------------------- missions

# An AMCL patrol on a real map; ``mission_text`` fills in the place, robot and waypoints.
PATROL_MISSION = """
name: {name}-{robot}
world: {world}
robot: {robot}
start: {start}
seed: {seed}
stack:
  localization: {{type: amcl}}
  global_planner: {{type: grid_astar}}
  local_planner: {{type: mpc}}
tasks:
  - type: patrol
    waypoints:
{waypoints}
    on_failure: skip
limits: {{time: {limit}}}
"""

HOUSE = {"name": "house-loc", "start": "{x: 3.83, y: -1.23, yaw: 0.0}", "seed": 3}
SHORT = [(6.5, -2.0, 0.0), (4.0, 0.5, 3.14)]
FULL = [(6.5, -2.0, 0.0), (2.0, 1.0, 3.14), (-1.5, 2.5, 1.57), (-5.0, -3.0, 3.14), (-6.0, 0.0, 0.0)]


def mission_text(waypoints, **fields) -> str:
    wps = "\n".join(f"      - {{x: {x}, y: {y}, yaw: {yaw}}}" for x, y, yaw in waypoints)
    return PATROL_MISSION.format(waypoints=wps, **fields)


def check_localisation(record, rmse_max: float, max_error: float) -> dict:
    assert record.status == "succeeded", record.reason
    loc = record.metrics["localization"]
    assert loc["position_rmse_settled"] <= rmse_max, loc
    assert loc["position_max_error_settled"] <= max_error, loc
    assert loc["consistency_2sigma"] >= 0.9, loc
    assert loc["refinement"]["accepted"] > 0.9 * loc["refinement"]["scans"]
    return loc


@pytest.mark.parametrize("robot", ["waffle", "burger"])
def test_real_aws_house_short_patrol_is_centimetre_accurate(tmp_path, ros_maps, robot):
    world = ros_maps / "aws_small_house" / "map.yaml"
    text = mission_text(SHORT, **HOUSE, robot=robot, world=world, limit=120)
    loaded = load_mission(tmp_path / "m.yaml", text=text)
    record = run_mission(loaded)
    check_localisation(record, 0.03, 0.10)
    # The covariance goes out with the run: result.json and trajectory.csv columns.
    assert record.covariance is not None and record.covariance.shape == (
        len(record.trajectory),
        4,
    )
    doc = write_run(tmp_path, loaded, record)
    final = doc["metrics"]["localization"]["final_covariance"]
    assert set(final) == {"xx", "xy", "yy", "yawyaw"} and final["xx"] > 0.0
    with (tmp_path / "trajectory.csv").open() as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == TRAJECTORY_COLUMNS + COVARIANCE_COLUMNS + ("battery",)
    assert float(rows[-1][9]) == pytest.approx(final["xx"], rel=1e-3)


def test_turtlebot3_profile_stays_selectable_on_the_real_house(tmp_path, ros_maps):
    world = ros_maps / "aws_small_house" / "map.yaml"
    text = mission_text(SHORT[:1], **HOUSE, robot="waffle", world=world, limit=60)
    overrides = ["stack.localization.profile=turtlebot3"]
    record = run_mission(load_mission(tmp_path / "m.yaml", overrides, text=text))
    assert record.status == "succeeded", record.reason
    loc = record.metrics["localization"]
    assert "refinement" not in loc  # amcl alone
    assert loc["position_rmse"] > 0.01  # amcl's particle estimate: centimetres, not mm
    assert 0.0 <= loc["consistency_2sigma"] <= 1.0  # the cloud's covariance is reported


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["waffle", "burger"])
def test_real_aws_house_patrol_over_five_poses(tmp_path, ros_maps, robot):
    world = ros_maps / "aws_small_house" / "map.yaml"
    text = mission_text(FULL, **HOUSE, robot=robot, world=world, limit=400)
    record = run_mission(load_mission(tmp_path / "m.yaml", text=text))
    check_localisation(record, 0.03, 0.10)
    assert record.metrics["distance_driven"] > 20.0


LARGE = {"name": "large-loc", "start": "{x: 2.0, y: 2.0, yaw: 0.0}", "seed": 5, "limit": 1200}

WAREHOUSE = [(6.0, 24.0, 1.57), (6.0, 47.5, 0.0), (18.0, 47.5, -1.57), (18.0, 24.0, 0.0)]
DEPOT = [(15.0, 7.5, 0.0), (27.0, 12.5, 1.57), (12.5, 7.5, 3.14), (3.0, 12.5, 1.57)]


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["waffle", "burger"])
@pytest.mark.parametrize(
    ("world", "waypoints"),
    [("loc_warehouse.yaml", WAREHOUSE), ("loc_depot.yaml", DEPOT)],
    ids=["warehouse", "depot"],
)
def test_large_open_maps_are_never_lost(tmp_path, world, waypoints, robot):
    text = mission_text(waypoints, **LARGE, robot=robot, world=WORLDS / world)
    record = run_mission(load_mission(tmp_path / "m.yaml", text=text))
    check_localisation(record, 0.06, 0.25)
    assert record.metrics["localization"]["refinement"]["restarts"] == 0


@pytest.mark.slow
def test_demo_patrol_is_not_worse_and_consistent_on_a_rasterised_map():
    demo = Path(__file__).resolve().parents[1] / "missions" / "patrol.yaml"
    record = run_mission(load_mission(demo))
    loc = check_localisation(record, 0.026, 0.05)
    assert loc["position_rmse"] <= 0.026
