"""grid SLAM on real MuJoCo scans: scan matching, mapping, drift against odometry,
frontiers and map quality."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import ndimage

from agv_mission.geometry import Pose2D, wrap_angle, wrap_angles
from agv_mission.mapping.frontiers import find_frontiers, frontier_mask
from agv_mission.mapping.likelihood_field import LikelihoodField, block_maxima
from agv_mission.mapping.quality import map_quality
from agv_mission.mapping.scan_matching import CorrelativeMatcher
from agv_mission.mapping.slam import GridSlam, GridSlamConfig, trajectory_rmse
from agv_mission.maps.builtin_worlds import small_house, turtlebot3_world
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import FREE, OCCUPIED, UNKNOWN, OccupancyGrid
from agv_mission.maps.worlds import World
from agv_mission.registry import registry
from agv_mission.robots.diff_drive import DiffDriveBody, SimConfig
from slam_drive import BURGER, GARBAGE, TB3_BOUNDS, Drive, drive

# A loop through the pillar field of turtlebot3_world, and back to the first corner.
TB3_LOOP = ((1.9, -0.55), (1.9, 0.55), (-1.9, 0.55), (-1.9, -0.55), (1.9, -0.55))
# Odometry noise and slip that make dead reckoning drift by decimetres within a minute; the
# lidar with a constant 1 cm noise and no dropouts (these tests measure the matcher against
# odometry, not the realistic defaults).
LIDAR_1CM = {"ideal": True, "lidar_noise": 0.01}
NOISY = SimConfig(**LIDAR_1CM, encoder_noise=0.05, wheel_slip=0.1)


@pytest.fixture(scope="module")
def tb3() -> World:
    return turtlebot3_world()


@pytest.fixture(scope="module")
def noisy_loop(tb3: World) -> Drive:
    return drive(tb3, TB3_LOOP, NOISY)


def scans_at(world: World, pose: Pose2D, n: int = 1, noise: float | None = None):
    config = SimConfig(ideal=True, lidar_noise=0.01 if noise is None else noise)
    sim = DiffDriveBody.alone(BURGER, world, pose, config, np.random.default_rng(3))
    return [sim.scan() for _ in range(n)]


def static_map(world: World, pose: Pose2D, scans: int = 4, **config) -> GridSlam:
    """A SLAM map built from a few scans taken standing at ``pose``."""
    slam = GridSlam(GridSlamConfig(**config), bounds=TB3_BOUNDS)
    slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
    for k, scan in enumerate(scans_at(world, pose, scans)):
        if k == 0:
            slam.update(Pose2D(0.0, 0.0, 0.0), scan, GARBAGE, 0.0)
        else:
            slam._integrate(scan, pose)  # same pose again: no motion, no match
    return slam


# --------------------------------------------------------------------------- plugin


def test_registered_with_defaults() -> None:
    cls = registry.get("slam", "grid")
    assert cls is GridSlam
    config = cls.Config()
    assert config.type == "grid" and config.resolution == 0.05
    assert registry.names("slam") == ["graph", "grid"]
    slam = registry.create("slam", config, bounds=TB3_BOUNDS, rng=np.random.default_rng(0))
    assert isinstance(slam, GridSlam)
    with pytest.raises(ValueError):
        GridSlamConfig(unknown_key=1)
    with pytest.raises(ValueError):
        GridSlam(GridSlamConfig(), bounds=(1.0, 0.0, 0.0, 1.0))


def test_map_is_allocated_on_the_lattice_around_the_bounds() -> None:
    slam = GridSlam(GridSlamConfig(map_margin=0.5), bounds=(-2.02, 3.0, -1.0, 1.0))
    grid = slam.occupancy_grid()
    assert grid.resolution == 0.05
    assert grid.origin.x == pytest.approx(-2.55) and grid.origin.y == pytest.approx(-1.5)
    xmin, xmax, ymin, ymax = grid.extent
    assert xmax >= 3.5 - 1e-9 and ymax >= 1.5 - 1e-9
    assert (grid.data == UNKNOWN).all()


def test_log_odds_integration_and_trinary_thresholds(tb3: World) -> None:
    pose = Pose2D(-2.0, -0.5, 0.3)
    # The log-odds alone (walls at their faces: test_walls_are_drawn_at_their_faces).
    slam = GridSlam(GridSlamConfig(wall_faces=False), bounds=TB3_BOUNDS)
    slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
    scan = scans_at(tb3, pose)[0]
    slam._integrate(scan, pose)
    grid = slam.occupancy_grid()
    # One hit makes a cell occupied (p 0.7 > 0.65); one pass-through is not yet free.
    ends = scan.points(pose)
    assert (grid.value_at(ends) == OCCUPIED).mean() > 0.95
    assert grid.counts()["free"] == 0
    slam._integrate(scan, pose)
    slam._integrate(scan, pose)  # three misses: p < 0.25
    grid = slam.occupancy_grid()
    mid = np.array([pose.x, pose.y]) + 0.5 * (ends - np.array([pose.x, pose.y]))
    assert (grid.value_at(mid) == FREE).mean() > 0.99  # (half-cell steps may skip a corner)
    assert grid.value_at(np.array([pose.x, pose.y])) == FREE
    # Log-odds stay clamped however often a cell is seen.
    for _ in range(20):
        slam._integrate(scan, pose)
    c = slam.config
    assert slam.log_odds.min() >= c.log_odds_min and slam.log_odds.max() <= c.log_odds_max


def test_map_grows_past_its_initial_extent(tb3: World) -> None:
    pose = tb3.spawn
    slam = GridSlam(GridSlamConfig(initial_size=2.0, grow_step=1.0))
    slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
    before = slam.occupancy_grid().extent
    slam.update(Pose2D(0.0, 0.0, 0.0), scans_at(tb3, pose)[0], GARBAGE, 0.0)
    grid = slam.occupancy_grid()
    xmin, xmax, ymin, ymax = grid.extent
    assert xmax - xmin > before[1] - before[0] + 2.0
    ox, oy = grid.origin.x / 0.05, grid.origin.y / 0.05
    assert ox == pytest.approx(round(ox)) and oy == pytest.approx(round(oy))
    # The arena's far wall (x ~ 2.9 at y ~ -0.5, 4.9 m away) is beyond the lidar; the
    # near west wall (2.5 m / cos 30 = 2.89 m from the centre) is mapped where it is.
    hits = scans_at(tb3, pose)[0].points(pose)
    assert (near_wall(grid).value_at(hits) == OCCUPIED).mean() > 0.95


def near_wall(grid: OccupancyGrid) -> OccupancyGrid:
    """``grid`` with every cell next to an OCCUPIED one OCCUPIED: a return falls in the
    cell its wall's face crosses, which is drawn as wall or lies in front of one
    (test_walls_are_drawn_at_their_faces)."""
    wall = ndimage.binary_dilation(np.asarray(grid.data) == OCCUPIED, np.ones((3, 3), bool))
    data = np.where(wall, OCCUPIED, grid.data).astype(np.int8)
    return OccupancyGrid(data, grid.resolution, grid.origin)


def test_reset_starts_a_new_map(tb3: World) -> None:
    slam = static_map(tb3, tb3.spawn)
    assert slam.occupancy_grid().counts()["occupied"] > 100
    slam.reset(Pose2D(0.55, 0.55, 0.0), Pose2D(0.0, 0.0, 0.0))
    assert slam.occupancy_grid().counts()["occupied"] == 0
    assert slam.trajectory == [] and slam.integrations == 0


# --------------------------------------------------------------------------- matching


def test_block_maxima_bound_every_cell_of_their_blocks() -> None:
    rng = np.random.default_rng(0)
    values = rng.random((23, 17)).astype(np.float32)
    levels = block_maxima(values, 8)
    assert sorted(levels) == [1, 2, 4, 8]
    for b, flat in levels.items():
        out = flat.reshape(values.shape)
        for r in range(23):
            for c in range(17):
                assert out[r, c] == values[r : r + b, c : c + b].max()
    with pytest.raises(ValueError):
        block_maxima(values, 3)


@pytest.mark.parametrize("refinement", ["icp", "field"])
def test_matcher_recovers_a_large_offset_on_a_real_scan(tb3: World, refinement: str) -> None:
    """From 0.15 m and 7 degrees off, the branch-and-bound search finds the right basin
    and the refinement lands within a few millimetres / milliradians."""
    pose = Pose2D(-1.5, -0.55, 0.4)
    slam = static_map(tb3, pose, refinement=refinement)
    field = slam.likelihood_field()
    matcher = slam.matcher
    scan = scans_at(tb3, pose, 5)[-1]
    points = slam._scan_points(scan)
    for dx, dy, dyaw in ((0.15, -0.1, 0.12), (-0.12, 0.15, -0.1), (0.0, 0.0, 0.0)):
        guess = pose.as_array() + [dx, dy, dyaw]
        result = matcher.match(field, points, guess)
        assert result.refined
        assert np.hypot(*(result.pose[:2] - pose.as_array()[:2])) < 0.01
        assert abs(wrap_angle(result.pose[2] - pose.yaw)) < 0.005
        assert result.score > 0.7
        # The search itself: within one cell and one angular step of the truth.
        assert np.abs(result.coarse_pose[:2] - pose.as_array()[:2]).max() <= 0.05 + 1e-9


def test_the_search_is_skipped_only_for_a_small_turn(tb3: World) -> None:
    """From a prediction 2 degrees off, the refinement alone lands on the truth and, with
    the default bound (a quarter of the 10 deg window), the search is skipped; with
    ``fast_turn`` below that correction the search runs, and lands there too."""
    pose = Pose2D(-1.5, -0.55, 0.4)
    slam = static_map(tb3, pose)
    field = slam.likelihood_field()
    points = slam._scan_points(scans_at(tb3, pose, 5)[-1])
    guess = pose.as_array() + [0.01, -0.01, math.radians(2.0)]
    prior = np.diag([0.05, 0.05, 0.05]) ** 2
    for fast_turn, searched in ((None, False), (math.radians(1.0), True)):
        matcher = CorrelativeMatcher(fast_score=0.5, fast_turn=fast_turn)
        result = matcher.match(field, points, guess, prior)
        assert (result.candidates > 0) == searched
        assert np.hypot(*(result.pose[:2] - pose.as_array()[:2])) < 0.01
        assert abs(wrap_angle(result.pose[2] - pose.yaw)) < 0.005


@pytest.mark.parametrize("coarse_block", [2, 4, 8])
def test_matcher_search_equals_exhaustive_search(tb3: World, coarse_block: int) -> None:
    """Branch and bound returns the same cell-level optimum as scoring every candidate."""
    pose = Pose2D(0.55, -0.55, -0.7)
    slam = static_map(tb3, pose)
    field = LikelihoodField(slam.map.field, 0.05, slam.origin)
    points = slam._scan_points(scans_at(tb3, pose, 2)[-1])
    guess = pose.as_array() + [0.08, -0.06, 0.05]
    fast = CorrelativeMatcher(refinement="none", angular_step=0.02, coarse_block=coarse_block)
    result = fast.match(field, points, guess)
    best, best_pose = -1.0, None
    for a in np.arange(-9, 10) * 0.02:
        for dy in np.arange(-4, 5) * 0.05:
            for dx in np.arange(-4, 5) * 0.05:
                cand = guess + [dx, dy, a]
                s = fast.score(field, points, cand) * fast._penalty(np.hypot(dx, dy), a)
                if s > best + 1e-12:
                    best, best_pose = s, cand
    found = fast.score(field, points, result.coarse_pose) * fast._penalty(
        np.hypot(*(result.coarse_pose[:2] - guess[:2])), result.coarse_pose[2] - guess[2]
    )
    assert found == pytest.approx(best, abs=1e-6)
    assert np.abs(result.coarse_pose - best_pose).max() < 0.06
    assert result.candidates < 19 * 81  # it did not have to score them all


def house_submap(slam: GridSlam) -> np.ndarray:
    """Map-frame scan points of the small house seen from three poses: a loop's submap."""
    house, xy = small_house(), []
    for pose in (Pose2D(-6.0, -1.0, 0.3), Pose2D(-3.0, 2.0, 1.2), Pose2D(5.0, 1.0, -2.0)):
        q = slam._scan_points(scans_at(house, pose, 1)[-1])
        c, s = math.cos(pose.yaw), math.sin(pose.yaw)
        xy.append(
            np.stack([pose.x + c * q[:, 0] - s * q[:, 1], pose.y + s * q[:, 0] + c * q[:, 1]], 1)
        )
    return np.vstack(xy)


@pytest.mark.parametrize("weights", [(0.0, 0.0), (1.0, 1.0)])
def test_a_wide_search_over_many_levels_finds_the_exhaustive_optimum(weights) -> None:
    """A loop's wide search (+-2 m, +-0.4 rad on 10 cm cells, blocks from 32 cells down):
    the very optimum of scoring every candidate (a top block of one cell)."""
    slam = GridSlam(GridSlamConfig())
    field = LikelihoodField.from_points(house_submap(slam), 0.1, 0.1)
    truth = Pose2D(-5.5, -0.5, 0.1)
    points = slam._scan_points(scans_at(small_house(), truth, 1)[-1])
    guess = truth.as_array() + [1.3, -0.9, 0.25]
    wt, wr = weights
    found = {}
    for block in (1, 4, 32):
        matcher = CorrelativeMatcher(
            linear_window=2.0,
            angular_window=0.4,
            coarse_block=block,
            translation_weight=wt,
            rotation_weight=wr,
            refinement="none",
        )
        result = matcher.match(field, points, guess)
        found[block] = (result.coarse_pose, result.candidates)
        assert np.array_equal(matcher.optimum(field, points, guess), result.pose)
    assert found[1][1] % (41 * 41) == 0  # one cell blocks: every cell at every angle
    for block in (4, 32):
        assert np.array_equal(found[block][0], found[1][0])
        assert found[block][1] < found[1][1] / 20
    if wt == 0.0:
        assert np.hypot(*(found[1][0][:2] - truth.as_array()[:2])) < 0.15


def test_a_field_cut_to_what_the_search_reads_finds_the_same_optimum() -> None:
    """A loop's searches read its submap only near the guess: the field of the submap's
    points cut to each one's box is smaller and gives the very same optimum, coarse (the
    wide search's square) and refined (where every point of the scan may land)."""
    slam = GridSlam(GridSlamConfig())
    xy = house_submap(slam)
    truth = Pose2D(-5.5, -0.5, 0.1)
    points = slam._scan_points(scans_at(small_house(), truth, 1)[-1])
    guess = truth.as_array() + [0.3, -0.25, 0.15]
    matcher = CorrelativeMatcher(
        linear_window=0.5,
        angular_window=0.4,
        coarse_block=8,
        refinement="none",
        search_max_range=2.0,
    )
    res = 0.1
    full = LikelihoodField.from_points(xy, res, 0.1)
    cut = LikelihoodField.from_points(xy, res, 0.1, matcher.read_box(points, guess, res))
    assert cut.values.size < full.values.size / 2
    found = matcher.match(cut, points, guess).coarse_pose
    assert np.array_equal(found, matcher.match(full, points, guess).coarse_pose)
    assert np.hypot(*(found[:2] - truth.as_array()[:2])) < 0.15

    refiner = CorrelativeMatcher(linear_window=0.3, angular_window=0.05, search_max_range=2.0)
    res = 0.05
    full = LikelihoodField.from_points(xy, res, 0.05)
    cut = LikelihoodField.from_points(xy, res, 0.05, refiner.read_box(points, found, res))
    assert cut.values.size < full.values.size * 0.8
    refined = refiner.match(cut, points, found)
    assert refined.refined
    assert np.array_equal(refined.pose, refiner.match(full, points, found).pose)
    assert np.hypot(*(refined.pose[:2] - truth.as_array()[:2])) < 0.03


def test_the_far_face_of_a_thin_wall_is_no_partner() -> None:
    """The livingroom face of the 10 cm bedroom wall is mapped; from the bedroom the
    robot sees the wall's other face for the first time. Paired with the mapped face, the
    match would move the robot a wall's thickness east; the faces' sides tell them apart."""
    world = small_house()
    slam = static_map(world, Pose2D(-1.5, -1.7, 0.0))
    prior = np.diag([0.05**2, 0.05**2, 0.05**2])
    for truth in (Pose2D(-3.2, -1.7, 0.3), Pose2D(-3.0, -2.0, 0.0), Pose2D(-3.5, -1.5, -0.2)):
        points = slam._scan_points(scans_at(world, truth)[0])
        field = slam.likelihood_field()
        result = slam.matcher.match(field, points, truth.as_array(), prior)
        assert result.refined
        assert math.hypot(result.pose[0] - truth.x, result.pose[1] - truth.y) < 0.015
        field.view = None  # blind to sides: pulled towards the mapped face
        blind = slam.matcher.match(field, points, truth.as_array(), prior)
        assert blind.pose[0] - truth.x > 0.03


def test_matcher_keeps_the_prediction_along_a_featureless_wall() -> None:
    """Along one straight wall the scan says nothing about the along-wall position: the
    odometry prior keeps it instead of a noisy cell jump."""
    res = 0.05
    occ = np.zeros((80, 120), bool)
    occ[60, :] = True  # a wall along x at y = 3.025
    field = LikelihoodField.from_occupied(occ, res, (0.0, 0.0), 0.05)
    rng = np.random.default_rng(1)
    xs = np.linspace(-2.0, 2.0, 120)
    pose = np.array([3.0, 1.0, 0.0])
    pts = np.stack([xs, np.full_like(xs, 2.025) + rng.normal(0, 0.01, xs.size)], 1)
    matcher = CorrelativeMatcher()
    prior = np.diag([0.01, 0.01, 0.01]) ** 2
    guess = pose + [0.013, 0.03, 0.0]
    result = matcher.match(field, pts, guess, prior)
    assert abs(result.pose[1] - pose[1]) < 0.01  # across the wall: corrected
    assert abs(result.pose[0] - guess[0]) < 0.01  # along it: the prediction stands


def test_a_match_the_odometry_rules_out_is_rejected(tb3: World) -> None:
    """The scan says the robot stands 0.15 m from where the odometry, a centimetre of
    driving on, puts it: far outside the prediction's covariance. Matched without the
    odometry prior, the scan alone decides: without a gate the match is taken; with one
    the prediction stands and the match counts as gated."""
    pose = Pose2D(-1.5, -0.55, 0.4)
    seen_from = Pose2D(pose.x + 0.15, pose.y, pose.yaw)
    scan = scans_at(tb3, seen_from, 2)[-1]
    moved = Pose2D(0.01, 0.0, 0.0)
    results = {}
    for gate in (None, 16.3):
        slam = static_map(tb3, pose, match_gate=gate, odom_prior=False)
        results[gate] = slam.update(moved, scan, GARBAGE, 1.0)
        assert slam.gated_matches == (0 if gate is None else 1)
        assert slam.diagnostics()["gated_matches"] == slam.gated_matches
    assert results[None].distance_to(seen_from) < 0.02
    assert results[16.3].distance_to(pose.compose(moved)) < 1e-9


# --------------------------------------------------------------------------- SLAM runs


def test_slam_corrects_odometry_drift_with_noisy_encoders(noisy_loop: Drive) -> None:
    run = noisy_loop
    slam_rmse = trajectory_rmse(run.estimate, run.truth)
    odom_rmse = trajectory_rmse(run.odometry, run.truth)
    final_odom = float(np.hypot(*(run.odometry[-1, :2] - run.truth[-1, :2])))
    yaw_err = np.abs(wrap_angles(run.estimate[:, 2] - run.truth[:, 2]))
    assert len(run.truth) > 600  # the loop was driven (about 80 s)
    assert slam_rmse <= 0.05
    assert odom_rmse >= 0.1 and odom_rmse >= 5.0 * slam_rmse
    assert final_odom > 0.2
    assert yaw_err.max() < 0.05
    assert run.slam.matches > 300 and run.slam.rejected_matches == 0
    # The plugin's own trajectory is the corrected pose at each processed scan.
    traj = np.array(run.slam.trajectory)
    assert traj.shape[1] == 4 and len(traj) == run.slam.matches + 1


def test_built_map_matches_the_world(noisy_loop: Drive, tb3: World) -> None:
    grid = noisy_loop.slam.occupancy_grid()
    q = map_quality(grid, tb3.map, TB3_BOUNDS, tb3.spawn.xy)
    assert q["free_iou"] >= 0.9
    assert q["coverage"] >= 0.9
    # Hits mark the wall faces the robot saw; the truth fills whole walls and pillars.
    assert q["occupied_iou"] > 0.25
    # No free cell inside an obstacle: only cells on its boundary (the truth marks a cell
    # occupied when any sliver of it is, the scan sees the face crossing it) may differ.
    face = ndimage.binary_dilation(tb3.map.data == FREE, structure=np.ones((3, 3), bool))
    deep = np.argwhere((tb3.map.data == OCCUPIED) & ~face)
    xy = tb3.map.cell_to_world(deep[:, 0], deep[:, 1])
    assert len(deep) > 300
    assert (grid.value_at(xy) == FREE).mean() < 0.005


def test_slam_map_feeds_a_costmap(noisy_loop: Drive) -> None:
    grid = noisy_loop.slam.occupancy_grid()
    costmap = Costmap.from_grid(grid, BURGER.footprint_radius)
    assert costmap.is_free(np.array([[-1.9, -0.55], [0.55, 0.55]])).all()
    assert not costmap.is_free(np.array([[-1.1, 0.0]])).any()  # a pillar


def test_noise_free_run_stays_exact(tb3: World) -> None:
    run = drive(tb3, TB3_LOOP[:2], SimConfig(**LIDAR_1CM))
    assert trajectory_rmse(run.estimate, run.truth) < 0.01


@pytest.mark.slow
def test_small_house_tour_with_noisy_encoders() -> None:
    world = small_house()
    route = (
        (3.0, -0.45), (-1.5, -0.45), (-1.5, -1.7), (-3.5, -1.7), (-5.5, -1.5), (-5.5, -3.5),
        (-8.0, -3.0), (-8.0, 0.0), (-4.0, 0.5), (-3.5, -1.7), (-1.5, -1.7), (-1.5, -0.45),
        (2.6, -0.45), (2.6, 1.6), (-1.0, 1.6), (-1.0, 4.6), (3.5, 4.6), (3.8, 1.6),
        (6.0, 1.6), (6.0, -0.5), (8.0, -1.0), (8.0, -3.5), (6.0, -2.8), (3.5, -2.8),
    )  # fmt: skip
    run = drive(world, route, NOISY, bounds=(-9.5, 9.5, -5.5, 5.5))
    slam_rmse = trajectory_rmse(run.estimate, run.truth)
    assert slam_rmse <= 0.05
    assert trajectory_rmse(run.odometry, run.truth) > 10 * slam_rmse
    q = map_quality(run.slam.occupancy_grid(), world.map, (-9.5, 9.5, -5.5, 5.5))
    assert q["free_iou"] >= 0.9


# --------------------------------------------------------------------------- frontiers


def test_frontiers_on_a_partial_map(tb3: World) -> None:
    slam = static_map(tb3, tb3.spawn)
    grid = slam.occupancy_grid()
    frontiers = find_frontiers(grid, TB3_BOUNDS, robot=tb3.spawn.xy)
    assert len(frontiers) >= 2
    costmap = Costmap.from_grid(grid, BURGER.footprint_radius)
    dists = [f.distance for f in frontiers]
    assert dists == sorted(dists) and all(np.isfinite(dists))
    for f in frontiers:
        assert f.size >= 5 and f.goal is not None
        # Each goal: known free space where the footprint fits, near its frontier.
        assert costmap.is_free(np.array([f.goal]), margin=0.04).all()
        assert np.min(np.hypot(*(f.cells - np.array(f.goal)).T)) <= 1.0 + 1e-9
        assert f.distance >= math.dist(f.goal, tb3.spawn.xy) - 0.1
        # Frontier cells are free cells next to unknown space.
        assert (grid.value_at(f.cells) == FREE).all()
    # Bounds filter: nothing outside them.
    small = (-2.5, -1.5, -1.0, 0.0)
    for f in find_frontiers(grid, small, robot=tb3.spawn.xy, reachable_only=False):
        assert (f.cells[:, 0] >= -2.5).all() and (f.cells[:, 0] <= -1.5).all()
        assert (f.cells[:, 1] >= -1.0).all() and (f.cells[:, 1] <= 0.0).all()
    # A blacklisted goal removes its frontier.
    first = frontiers[0]
    rest = find_frontiers(grid, TB3_BOUNDS, robot=tb3.spawn.xy, blacklist=[first.goal])
    assert all(f.goal != first.goal for f in rest)


def test_frontiers_vanish_when_the_map_is_complete(tb3: World, noisy_loop: Drive) -> None:
    assert find_frontiers(tb3.map, robot=tb3.spawn.xy) == []
    assert not frontier_mask(tb3.map).any()
    house = small_house()
    assert find_frontiers(house.map, robot=house.spawn.xy) == []
    # After the loop only small leftovers (behind pillars) remain, if any.
    grid = noisy_loop.slam.occupancy_grid()
    partial = static_map(tb3, tb3.spawn).occupancy_grid()
    after = find_frontiers(grid, TB3_BOUNDS, robot=tuple(noisy_loop.estimate[-1, :2]))
    before = find_frontiers(partial, TB3_BOUNDS, robot=tb3.spawn.xy)
    assert sum(f.size for f in after) < 0.2 * sum(f.size for f in before)


def test_unknown_pockets_are_not_frontiers() -> None:
    data = np.zeros((40, 40), np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = OCCUPIED
    data[18:23, 18:23] = OCCUPIED
    data[19:22, 19:22] = UNKNOWN  # the inside of a pillar
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    assert find_frontiers(grid, robot=(0.5, 0.5)) == []
    data[19:22, 22] = FREE  # a gap in the ring: the pocket borders free space
    assert frontier_mask(grid).any()
    assert find_frontiers(grid, robot=(0.5, 0.5), min_size=1) == []  # still a pocket
    assert find_frontiers(grid, robot=(0.5, 0.5), min_size=1, min_unknown=0)


def test_shadow_pockets_are_frontiers() -> None:
    """A small unknown pocket ringed by free cells is a lidar shadow, not an object's
    inside: it stays a frontier (left unknown, it blocks the costmap)."""
    data = np.zeros((60, 60), np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = OCCUPIED
    data[18:23, 18:23] = OCCUPIED
    data[19:22, 19:22] = UNKNOWN  # the inside of a pillar
    data[40:43, 10:30] = UNKNOWN  # a 60-cell shadow in open space
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    (shadow,) = find_frontiers(grid, robot=(0.5, 0.5))
    assert 39 <= shadow.centroid[1] / 0.05 <= 44 and shadow.goal is not None
    # ... unless open pockets are ignored too
    assert find_frontiers(grid, robot=(0.5, 0.5), open_share=1.1) == []


def test_goals_keep_a_margin_where_there_is_room() -> None:
    data = np.full((60, 60), UNKNOWN, np.int8)
    data[10:50, 5:40] = FREE  # a room whose east side is unexplored
    data[9, 4:40] = data[50, 4:40] = data[9:51, 4] = OCCUPIED
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    costmap = Costmap.from_grid(grid, BURGER.footprint_radius)
    need = BURGER.footprint_radius + 0.05
    robot = (0.75, 1.5)
    (tight,) = find_frontiers(grid, robot=robot)
    (roomy,) = find_frontiers(grid, robot=robot, goal_margin=0.1)
    assert need < costmap.clearance(np.array(tight.goal)) <= need + 0.1
    assert costmap.clearance(np.array(roomy.goal)) > need + 0.1
    assert np.min(np.hypot(*(roomy.cells - np.array(roomy.goal)).T)) <= 1.0 + 1e-9


def test_unreachable_frontier_has_no_goal() -> None:
    data = np.full((60, 60), UNKNOWN, np.int8)
    data[5:25, 5:25] = FREE  # the robot's room
    data[40:55, 40:55] = FREE  # a separate, unreachable patch
    grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
    reachable = find_frontiers(grid, robot=(0.75, 0.75))
    everything = find_frontiers(grid, robot=(0.75, 0.75), reachable_only=False)
    assert len(reachable) == 1 and len(everything) == 2
    lost = [f for f in everything if f.goal is None]
    assert len(lost) == 1 and lost[0].centroid[0] > 2.0 and math.isinf(lost[0].distance)


# --------------------------------------------------------------------------- quality


def test_map_quality_of_the_truth_is_perfect(tb3: World) -> None:
    for world in (tb3, small_house()):
        q = map_quality(world.map, world.map, None, world.spawn.xy)
        assert q["occupied_iou"] == 1.0 and q["free_iou"] == 1.0 and q["coverage"] == 1.0


def test_map_quality_counts_errors_and_resamples(tb3: World) -> None:
    truth = tb3.map
    worse = OccupancyGrid(truth.data.copy(), truth.resolution, truth.origin)
    free = np.argwhere(worse.data == FREE)
    worse.data[tuple(free[: len(free) // 4].T)] = UNKNOWN
    q = map_quality(worse, truth, TB3_BOUNDS, tb3.spawn.xy)
    assert q["coverage"] == pytest.approx(0.75, abs=0.01)
    assert q["free_iou"] == pytest.approx(0.75, abs=0.01)
    assert q["occupied_iou"] == 1.0
    # The same map at 2.5 cm (each cell split in four) compares equal after resampling.
    fine = OccupancyGrid(np.kron(truth.data, np.ones((2, 2), np.int8)), 0.025, truth.origin)
    q = map_quality(fine, truth, TB3_BOUNDS, tb3.spawn.xy)
    assert q["free_iou"] == 1.0 and q["occupied_iou"] == 1.0


def _face_offsets(grid: OccupancyGrid, world: World) -> np.ndarray:
    """The world's signed distance (m, negative inside walls) at the centres of the map's
    OCCUPIED cells that border FREE ones: -res / 2 where the map draws a wall's face
    where the world has it, +res / 2 where it draws it a cell in front."""
    from agv_mission.localization.distance_field import SignedDistanceField

    data = np.asarray(grid.data)
    border = (data == OCCUPIED) & ndimage.binary_dilation(data == FREE)
    rows, cols = np.nonzero(border)
    res = grid.resolution
    xy = np.stack([grid.origin.x + (cols + 0.5) * res, grid.origin.y + (rows + 0.5) * res], 1)
    values, _ = SignedDistanceField(world.map).lookup(xy)
    return values[np.abs(values) < 0.2]  # not the far side of a door's unmapped room


@pytest.mark.parametrize("noise", [0.01, 0.02])
def test_walls_are_drawn_at_their_faces(noise: float) -> None:
    """Noisy returns from a face on a cell boundary fall into the cells on both sides of
    it; drawn as they fall, the walls stand up to a cell proud of their faces (a
    localiser on that map is pushed off every wall). With the end points' means the map
    puts the face back on the boundary."""
    world = small_house()
    pose = Pose2D(-3.0, -2.0, 0.4)
    scans = scans_at(world, pose, 12, noise=noise)
    offsets = {}
    for faces in (True, False):
        slam = GridSlam(GridSlamConfig(wall_faces=faces), bounds=(-9.5, 9.5, -5.5, 5.5))
        slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
        for scan in scans:
            slam._integrate(scan, pose)
        offsets[faces] = _face_offsets(slam.occupancy_grid(), world)
    res = 0.05
    # Drawn as they fall: most border cells a cell in front of the faces (the world's
    # distance at their centres +res / 2 instead of -res / 2).
    assert np.mean(offsets[False] > 0.0) > 0.6
    assert offsets[False].mean() > -res / 2 + 0.6 * res
    # At their faces: most of them, and within a quarter of a cell on average.
    assert np.mean(offsets[True] > 0.0) < 0.3
    assert offsets[True].mean() < -res / 2 + 0.25 * res


@pytest.mark.parametrize("noise", [0.01, 0.02])
def test_the_faces_scatter_is_free_not_undecided(noise: float) -> None:
    """The cells just in front of a face (less than a cell) that caught some of its noisy
    returns: drawn at the faces, they are FREE, not UNKNOWN where their hits and the beams
    through them to the face came out about even (measured: 19-21 % of them UNKNOWN when
    only the OCCUPIED ones were moved back, 6-10 % now)."""
    from agv_mission.localization.distance_field import SignedDistanceField

    world = small_house()
    pose = Pose2D(-3.0, -2.0, 0.4)
    slam = GridSlam(GridSlamConfig(wall_faces=True), bounds=(-9.5, 9.5, -5.5, 5.5))
    slam.reset(pose, Pose2D(0.0, 0.0, 0.0))
    for scan in scans_at(world, pose, 12, noise=noise):
        slam._integrate(scan, pose)
    grid = slam.occupancy_grid()
    rows, cols = np.nonzero(slam.map.hn > 0)
    res = grid.resolution
    xy = np.stack([grid.origin.x + (cols + 0.5) * res, grid.origin.y + (rows + 0.5) * res], 1)
    distance, _ = SignedDistanceField(world.map).lookup(xy)
    front = (distance > 0.0) & (distance < res)
    assert front.sum() > 100
    assert np.mean(grid.data[rows[front], cols[front]] == UNKNOWN) < 0.15
