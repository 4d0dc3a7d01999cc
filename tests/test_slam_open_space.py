"""grid SLAM where the lidar sees little (issue 32, the depot): a scan that cannot
constrain the match along some direction leaves the odometry there."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agv_mission.geometry import Pose2D
from agv_mission.mapping.configs import GraphSlamConfig
from agv_mission.mapping.graph_slam import GraphSlam
from agv_mission.mapping.likelihood_field import LikelihoodField
from agv_mission.mapping.scan_matching import CorrelativeMatcher, fuse
from agv_mission.mapping.slam import GridSlam, GridSlamConfig
from agv_mission.maps.builtin_worlds import depot
from agv_mission.maps.worlds import World
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig
from slam_drive import BURGER

# The depot's west wall seen from 3 m with a constant 5 cm range noise: an LDS-01's
# 1.75 % at 3 m, too noisy for the point-to-line refinement's scan normals, so the
# correlative optimum is all the matcher has. The gyro's odometry prior, as the runner
# sets it (stack.GYRO_SLAM_NOISE), and the LDS-01's point std (10 cm).
WALL_NOISE = 0.05
SLAM = {
    "point_sigma": 0.1,
    "odom_rotation_noise": 0.003,
    "odom_rotation_per_metre": 0.003,
    "odom_rotation_floor": 1e-4,
}
DEPOT_BOUNDS = (-15.5, 15.5, -8.0, 8.0)


@pytest.fixture(scope="module")
def world() -> World:
    return depot()


def scans(world: World, pose: Pose2D, n: int, seed: int) -> list:
    config = SimConfig(ideal=True, lidar_noise=WALL_NOISE)
    sim = DiffDriveBody.alone(BURGER, world, pose, config, np.random.default_rng(seed))
    return [sim.scan() for _ in range(n)]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_driving_along_a_lone_wall_keeps_the_odometry_along_it(world: World, seed: int) -> None:
    """The robot drives 1 m along the west wall, 3 m away, with exact odometry. The
    wall's end points beyond the part mapped at the start score nothing, so the
    correlative optimum lies a cell or more back toward the mapped part, scan after
    scan (taken as it was, the estimate fell 0.15 to 0.75 m behind). The optimum's
    score surface is flat along the wall: fused with the odometry, it moves nothing
    there, and the estimate stays within centimetres."""
    start = Pose2D(-12.0, 0.0, -math.pi / 2)
    slam = GridSlam(GridSlamConfig(**SLAM), bounds=DEPOT_BOUNDS)
    slam.reset(start, Pose2D(0.0, 0.0, 0.0))
    first, *more = scans(world, start, 3, seed)
    slam.update(Pose2D(0.0, 0.0, 0.0), first, start, 0.0)
    for scan in more:
        slam._integrate(scan, start)  # standing: no motion, no match
    for i in range(1, 26):
        driven = 0.04 * i  # 0.2 m/s, a scan each 0.2 s
        truth = Pose2D(start.x, start.y - driven, start.yaw)
        scan = scans(world, truth, 1, 100 * seed + i)[0]
        estimate = slam.update(Pose2D(driven, 0.0, 0.0), scan, truth, 0.2 * i)
        assert estimate.distance_to(truth) < 0.03, i
    assert slam.matches == 25 and slam.rejected_matches == 0


def test_a_flat_score_surface_is_wide_along_the_wall() -> None:
    """A field holding one straight wall along x: the correlative optimum's covariance
    is wide along the wall and a cell's across it, and the Kalman update keeps the
    prediction along the wall while taking the correction across it."""
    res = 0.05
    occ = np.zeros((80, 200), bool)
    occ[60, :] = True  # y = 3.025
    field = LikelihoodField.from_occupied(occ, res, (0.0, 0.0), 0.05)
    xs = np.linspace(-2.0, 2.0, 80)
    pts = np.stack([xs, np.full_like(xs, 2.025)], 1)
    guess = np.array([5.0, 1.1, 0.0])  # 0.1 m off across the wall
    result = CorrelativeMatcher(refinement="none").match(field, pts, guess, None)
    assert result.covariance is not None
    sx, sy = np.sqrt(np.diag(result.covariance)[:2])
    assert sx > 0.08  # along: anywhere in the +-0.2 m window
    assert sy < 0.025  # across: a cell
    prior = np.diag([0.02, 0.02, 0.01]) ** 2
    moved = guess + [0.15, 0.0, 0.0]  # as if the optimum had slid 3 cells along it
    pose, _ = fuse(guess, prior, moved + [0.0, -0.1, 0.0], result.covariance)
    assert abs(pose[0] - guess[0]) < 0.01
    assert abs(pose[1] - 1.0) < 0.04  # most of the 0.1 m across


def test_a_loop_the_scan_cannot_pin_adds_no_edge() -> None:
    """A loop match's covariance widens its edge; one wide past half the loop window
    (a lone wall: anywhere along it) adds no edge at all, nor one wide past a third of
    loop_verify's shift: a ridge (the depot's east shelf, 0.2 m along it) whose wrong
    optimum would be taken unconfirmed."""
    slam = GraphSlam(GraphSlamConfig())
    assert slam._loop_sigma(np.diag([1e-4, 0.5, 1e-4]), 0.0) is None
    shelf = np.diag([0.06**2, 0.2**2, 0.05**2])
    assert 0.5 * slam.config.loop_linear_window > 0.2  # the window alone let it in
    assert slam._loop_sigma(shelf, 0.0) is None
    rotated = np.array([[0.02, 0.018, 0.0], [0.018, 0.02, 0.0], [0.0, 0.0, 1e-4]])
    assert slam._loop_sigma(rotated, 0.0) is None  # 0.19 m std along the diagonal
    assert slam._loop_sigma(np.diag([1e-4, 0.12**2, 1e-4]), 0.0) is None
    assert slam._loop_sigma(np.diag([1e-4, 0.09**2, 1e-4]), 0.0) is not None
    # 8 cm along world y, 1 cm across: seen from a keyframe facing +y, along its x
    sigma = slam._loop_sigma(np.diag([1e-4, 0.08**2, 1e-4]), math.pi / 2)
    assert sigma is not None
    assert sigma[0] == pytest.approx(0.08) and sigma[1] == pytest.approx(0.05)
    assert np.allclose(slam._loop_sigma(np.diag([1e-6, 1e-6, 1e-6]), 0.3), [0.05, 0.05, 0.05])
