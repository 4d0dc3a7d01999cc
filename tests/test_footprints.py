"""Robots as their datasheets (robots-and-worlds.md, "Robots"): polygon footprints used by
the costmap, the MPC, the collision monitor, the simulated body and the clearance metric;
the lidar's field of view and mount; the built-in Jackal."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from agv_mission.geometry import Footprint, Pose2D
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.worlds import Cylinder, World
from agv_mission.planners.base import VelocityLimits
from agv_mission.planners.collision_monitor import (
    CollisionMonitor,
    CollisionMonitorConfig,
    default_zones,
)
from agv_mission.planners.mpc import MpcConfig, MpcController
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.description import RobotDescription
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig
from agv_mission.robots.robot_files import RobotFileError, load_robot

JACKAL = BUILTIN_ROBOTS["jackal"]


def test_polygon_figures_and_disc_cover_hold_the_whole_body() -> None:
    fp = Footprint.from_points(JACKAL.footprint)
    assert fp.inscribed == pytest.approx(0.215)
    assert fp.circumscribed == pytest.approx(math.hypot(0.254, 0.215))
    assert (fp.half_width, fp.front, fp.back) == pytest.approx((0.215, 0.254, 0.254))
    centres, radius = fp.discs()
    assert len(centres) == 3 and radius - fp.half_width <= 0.02
    # every point of the body lies within the radius of some disc centre
    rng = np.random.default_rng(3)
    pts = rng.uniform([-0.254, -0.215], [0.254, 0.215], size=(4000, 2))
    d = np.hypot(pts[:, 0, None] - np.asarray(centres)[None, :], pts[:, 1, None]).min(axis=1)
    assert d.max() <= radius + 1e-9
    # an off-centre, clockwise polygon (the origin near its front) is covered too
    odd = Footprint.from_points([(0.08, -0.15), (-0.2, -0.15), (-0.2, 0.15), (0.08, 0.15)][::-1])
    assert odd.inscribed == pytest.approx(0.08)
    centres, radius = odd.discs()
    corners = odd.polygon
    gap = np.hypot(corners[:, 0, None] - np.asarray(centres)[None, :], corners[:, 1, None])
    assert gap.min(axis=1).max() <= radius + 1e-9
    # a round robot is one disc at its centre, as before
    assert Footprint.circle(0.105).discs() == ((0.0,), 0.105)


def test_robot_file_with_footprint_and_lidar_field_of_view(tmp_path: Path) -> None:
    path = tmp_path / "box.yaml"
    path.write_text(
        "wheel_radius: 0.05\nwheel_separation: 0.3\n"
        "footprint: [[0.3, 0.2], [-0.2, 0.2], [-0.2, -0.2], [0.3, -0.2]]\n"
        "max_linear_velocity: 1.0\nmax_angular_velocity: 2.0\n"
        "encoder: {ticks_per_meter: 1000}\n"
        "lidar: {beams: 181, angle_min: -1.5708, angle_max: 1.5708, mount: {x: 0.1}}\n"
    )
    robot = load_robot(str(path))
    assert robot.footprint_radius == pytest.approx(math.hypot(0.3, 0.2))  # the circle round it
    assert robot.inscribed_radius == pytest.approx(0.2)
    first, step = robot.lidar.beam_angles()
    assert first == pytest.approx(-1.5708) and step == pytest.approx(math.pi / 180, rel=1e-4)
    assert robot.lidar.scan_pose(Pose2D(1.0, 2.0, math.pi / 2)).as_array() == pytest.approx(
        [1.0, 2.1, math.pi / 2]
    )
    # a robot without a polygon keeps its circle and a full-turn lidar
    burger = BUILTIN_ROBOTS["burger"]
    assert burger.polygon is None and burger.inscribed_radius == burger.footprint_radius
    assert burger.lidar.beam_angles() == pytest.approx((0.0, 2 * math.pi / 360))


@pytest.mark.parametrize(
    ("text", "field", "line", "words"),
    [
        ("footprint: [[0.3, 0.2], [-0.2, -0.2], [-0.2, 0.2], [0.3, -0.2]]\n", "footprint", 3,
         "not a simple polygon"),
        ("footprint: [[0.3, 0.2], [0.2, 0.2], [0.2, 0.1], [0.3, 0.1]]\n", "footprint", 3,
         "origin"),
        ("footprint_radius: 0.2\nlidar: {angle_min: -1.0}\n", "lidar", 4, "go together"),
        ("", "", None, "footprint_radius"),
    ],
)  # fmt: skip
def test_bad_footprints_and_fields_of_view_name_line_and_field(
    tmp_path: Path, text: str, field: str, line: int | None, words: str
) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(
        "wheel_radius: 0.05\nwheel_separation: 0.3\n" + text + "max_linear_velocity: 1.0\n"
        "max_angular_velocity: 2.0\nencoder: {ticks_per_meter: 1000}\n"
    )
    with pytest.raises(RobotFileError) as err:
        load_robot(str(path))
    assert err.value.field == field and words in err.value.message
    if line is not None:
        assert err.value.line == line


def test_jackal_is_barns_jackal() -> None:
    lidar = JACKAL.lidar
    assert lidar.beams == 1081 and lidar.rate == 40.0 and lidar.range_max == 10.0
    first, step = lidar.beam_angles()
    assert math.degrees(step) == pytest.approx(0.25)
    assert math.degrees(first) == pytest.approx(-135.0)
    poly = shapely.Polygon(JACKAL.footprint)
    assert poly.bounds == pytest.approx((-0.254, -0.215, 0.254, 0.215))
    assert JACKAL.max_linear_velocity == 2.0
    assert RobotDescription.model_validate(JACKAL.model_dump()) == JACKAL  # round-trips


def test_simulated_jackal_is_its_box_lidar_sees_270_degrees_from_its_mount() -> None:
    # pillars: one beside the body within the circle round it but clear of the box
    # (0.215 m half-width), one 2 m ahead, one 2 m behind (outside the 270 degrees)
    grid = OccupancyGrid(np.zeros((40, 40), dtype=np.int8), 0.25, Pose2D(-5.0, -5.0))
    pillars = [Cylinder(0.0, 0.215 + 0.075 + 0.03, 0.075), Cylinder(2.0, 0.0, 0.075)]
    world = World("pillars", [], [*pillars, Cylinder(-2.0, 0.0, 0.075)], grid, Pose2D(0, 0))
    sim = DiffDriveBody.alone(
        JACKAL, world, Pose2D(0.0, 0.0, 0.0), SimConfig(ideal=True), np.random.default_rng(1)
    )
    sim.advance(0.2)
    assert sim.contacts() == 0
    circle, body = sim.clearances()
    assert circle < 0.0 < body == pytest.approx(0.03, abs=0.01)
    scan = sim.scan()
    assert len(scan.ranges) == 1081
    assert scan.angle_min == pytest.approx(-math.radians(135))
    ahead = scan.ranges[540]  # straight ahead, from the mount 0.055 m ahead of the origin
    assert ahead == pytest.approx(2.0 - 0.075 - 0.055, abs=0.01)
    # nothing behind: the pillar at -2 m lies in the 90 degrees the scanner does not see
    pts = scan.points(JACKAL.lidar.scan_pose(sim.true_pose()))
    assert not np.any(np.hypot(pts[:, 0] + 2.0, pts[:, 1]) < 0.2)


def test_collision_monitor_zones_and_turns_of_a_polygon() -> None:
    fp = JACKAL.polygon
    stop, slow, _ = default_zones(JACKAL.footprint_radius, fp)
    assert max(p[0] for p in stop.polygon) == pytest.approx(0.254 + 0.05)
    assert max(abs(p[1]) for p in stop.polygon) == pytest.approx(0.215)
    cm = CollisionMonitor(CollisionMonitorConfig(), JACKAL.footprint_radius, 0.1, fp)
    # a pillar by the front-left corner: turning left on the spot swings the corner into it
    pillar = np.array([[0.30, 0.05], [0.31, 0.06], [0.30, 0.07]])
    out = cm(0.0, 2.0, pillar)
    assert out.action == "approach" and abs(out.w) < 2.0
    # beside the body, 5 cm off its side, a pillar does not stop it driving on
    side = np.array([[0.0, 0.265], [0.05, 0.265], [-0.05, 0.265]])
    assert cm(1.0, 0.0, side).action == "none"
    # the round burger is as before: turning in place is free
    burger = CollisionMonitor(CollisionMonitorConfig(), 0.105, 0.1)
    assert burger(0.0, 2.0, np.array([[0.11, 0.0], [0.115, 0.0]])).w == 2.0


def test_mpc_keeps_the_jackals_box_clear_through_a_gap_its_circle_does_not_fit() -> None:
    """Two pillars 0.56 m apart (edge to edge) across a straight path: the Jackal's box
    (0.43 m wide) passes between them, its circle (0.67 m) would not."""
    limits = VelocityLimits(max_v=2.0, max_w=4.0, max_acc_v=2.0, max_acc_w=8.0)
    mpc = MpcController(MpcConfig(), limits, JACKAL.inscribed_radius, 0.1, footprint=JACKAL.polygon)
    assert len(mpc.discs) == 3
    a = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
    ring = 0.075 * np.column_stack([np.cos(a), np.sin(a)])
    pillars = np.vstack([ring + (3.0, 0.355), ring + (3.0, -0.355)])
    path = np.column_stack([np.linspace(0.0, 6.0, 61), np.zeros(61)])
    goal = Pose2D(6.0, 0.0, 0.0)
    pose, vel = Pose2D(0.0, 0.02, 0.0), (0.0, 0.0)
    nearest = math.inf
    for _ in range(80):
        cmd = mpc.compute(pose, vel, path, goal, pillars)
        pose, vel = pose.driven(cmd.v, cmd.w, 0.1), (cmd.v, cmd.w)
        placed = shapely.Polygon(Footprint.from_points(JACKAL.footprint).in_map(*pose.as_array()))
        nearest = min(nearest, float(shapely.distance(shapely.points(pillars), placed).min()))
    assert pose.x > 4.0  # through the gap
    assert nearest > 0.0  # never touched a pillar


# -- navigation at speed ---------------------------------------------------------------


def test_free_distance_stops_at_a_point_on_the_corridor_and_behind_an_occluder() -> None:
    from agv_mission.planners.free_corridor import free_distance

    samples = np.column_stack([np.arange(1, 31) * 0.1, np.zeros(30)])  # 0.1 .. 3.0 m ahead
    half = 0.265
    assert free_distance(samples, 0.1, (0.0, 0.0), np.zeros((0, 2)), half) == pytest.approx(3.0)
    # a return on the way 1.5 m ahead: free up to the sample before it reaches it
    on_path = np.array([[1.5, 0.1]])
    assert free_distance(samples, 0.1, (0.0, 0.0), on_path, half) == pytest.approx(1.2)
    # round a bend (1 m ahead, then left), a pillar by the inner corner hides the way on
    s = np.arange(1, 31) * 0.1
    bend = np.column_stack([np.minimum(s, 1.0), np.maximum(s - 1.0, 0.0)])
    a = np.linspace(0.0, 2 * math.pi, 36, endpoint=False)
    pillar = np.column_stack([0.6 + 0.075 * np.cos(a), 0.45 + 0.075 * np.sin(a)])
    hidden = free_distance(bend, 0.1, (0.0, 0.0), pillar, half)
    assert 1.0 <= hidden < 2.0
    assert free_distance(bend, 0.1, (0.0, 0.0), np.zeros((0, 2)), half) == pytest.approx(3.0)


def test_the_reference_stands_where_it_must_stop() -> None:
    from agv_mission.planners.path_tracking import ReferenceProfile

    path = np.array([[0.0, 0.0], [10.0, 0.0]])
    profile = ReferenceProfile(path, np.array([0.0, 10.0]), 2.0, 4.0, 2.0, 1.0)
    s, v = profile.sample(0.0, 1.0, 30, 0.1, stop_at=1.5)
    assert max(s) <= 1.5 + 0.01 and v[-1] == pytest.approx(0.0, abs=0.05)  # to a step
    # too close to stop at the reference's braking: it brakes from the first step (the
    # MPC itself may brake harder, to its acceleration limit)
    s, v = profile.sample(0.0, 2.0, 30, 0.1, stop_at=1.5)
    assert all(b <= a for a, b in zip(v, v[1:], strict=False)) and v[1] < 2.0
    free_s, free_v = profile.sample(0.0, 2.0, 30, 0.1)
    assert free_s[-1] > 5.0 and min(free_v) == pytest.approx(2.0)


def test_a_fast_robot_looks_further_ahead_a_turtlebot_as_before() -> None:
    from agv_mission.maps.costmap import ObstacleLayerConfig
    from agv_mission.missions.run.stack import tuned_for_speed
    from agv_mission.navigation.config import NavigationConfig

    nav, layer = NavigationConfig(), ObstacleLayerConfig()
    fast_nav, fast_layer = tuned_for_speed(JACKAL, nav, layer)
    assert fast_nav.blocked_lookahead == pytest.approx(4.0)  # twice its 2 m to stop
    assert fast_layer.max_range == pytest.approx(5.0) and fast_layer.raytrace_range >= 5.5
    for name in ("burger", "waffle"):
        assert tuned_for_speed(BUILTIN_ROBOTS[name], nav, layer) == (nav, layer)
    # what the mission sets stands
    mine = NavigationConfig(blocked_lookahead=1.0)
    assert tuned_for_speed(JACKAL, mine, layer)[0].blocked_lookahead == 1.0


@pytest.mark.slow
def test_a_jackal_crosses_pillars_it_cannot_see_past_at_speed(tmp_path: Path) -> None:
    """map: none, a pillar hidden behind another on the straight line to the goal (as in
    BARN's world 260, which a Jackal at full speed hit): it gets there untouched."""
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.run.runner import run_mission

    pillars = [(0.45, 2.0), (-0.45, 2.0), (0.0, 3.2), (0.3, 4.4), (-0.55, 4.4), (0.0, 5.6)]
    world = tmp_path / "pillars.yaml"
    world.write_text(
        "spawn: {x: 0.0, y: 0.0, yaw: 1.5708}\n"
        "bounds: {xmin: -3, xmax: 3, ymin: -1, ymax: 9}\ncylinders:\n"
        + "".join(f"  - {{x: {x}, y: {y}, radius: 0.075}}\n" for x, y in pillars)
    )
    mission = tmp_path / "m.yaml"
    mission.write_text(
        "world: pillars.yaml\nmap: none\nrobot: jackal\nseed: 2\n"
        "start: {x: 0.0, y: 0.0, yaw: 1.5708}\n"
        "tasks:\n  - {type: go_to, pose: {x: 0.0, y: 8.0, yaw: 1.5708}}\n"
        "limits: {time: 60.0}\noutput: {bag: false}\n"
    )
    record = run_mission(load_mission(mission))
    assert record.status == "succeeded", record.reason
    assert record.metrics["collisions"] == 0 and record.metrics["min_clearance"] > 0.0
    assert record.trajectory[:, 7].max() > 1.0  # it drove fast where it could


def test_the_vda5050_factsheet_gives_the_polygon() -> None:
    from agv_mission.vda5050.factsheet import factsheet_body

    def envelope(robot: RobotDescription) -> list[dict]:
        return factsheet_body(robot, 1.0, 1.0)["agvGeometry"]["envelopes2d"][0]["polygonPoints"]

    assert [(p["x"], p["y"]) for p in envelope(JACKAL)] == [tuple(p) for p in JACKAL.footprint]
    assert len(envelope(BUILTIN_ROBOTS["burger"])) == 8  # a round robot: its octagon
