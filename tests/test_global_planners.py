"""Global planners (OMPL and grid) on synthetic rooms, the real ROS maps and built-in worlds."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid
from agv_mission.planners.base import PlannedPath, PlanningError
from agv_mission.planners.configs import CostGridConfig, available_planners
from agv_mission.planners.cost_grid import CostGridPlanner
from agv_mission.planners.free_space import FreeSpace
from agv_mission.planners.grid_astar import GridAstarConfig, GridAstarPlanner
from agv_mission.planners.ompl_planner import THREADED_PLANNERS, OmplPlanner, OmplPlannerConfig
from agv_mission.planners.path_smoothing import segments_cells
from agv_mission.registry import registry

ROS_MAPS = Path(__file__).resolve().parent / "data" / "ros_maps"

RES = 0.05
ROBOT_RADIUS = 0.105
COSTMAP = CostmapConfig(inflation_radius=0.3)
OPTIMISING = ["RRTstar", "PRMstar", "BITstar", "InformedRRTstar"]


# --------------------------------------------------------------------------- helpers


def room_with_door(door: tuple[float, float] | None = (2.8, 3.6), yaw: float = 0.0) -> Costmap:
    """A 6 x 4 m room split by a wall at x = 3 with a door (y range) near the top."""
    data = np.full((80, 120), FREE, dtype=np.int8)
    data[:2, :] = data[-2:, :] = OCCUPIED
    data[:, :2] = data[:, -2:] = OCCUPIED
    data[:, 59:61] = OCCUPIED
    if door is not None:
        data[int(door[0] / RES) : int(door[1] / RES), 59:61] = FREE
    grid = OccupancyGrid(data, RES, Pose2D(0.0, 0.0, yaw))
    return Costmap.from_grid(grid, ROBOT_RADIUS, COSTMAP)


def to_world(costmap: Costmap, x: float, y: float) -> Pose2D:
    """Room coordinates (metres from the map corner, along the grid) to the map frame."""
    o = costmap.grid.origin
    c, s = math.cos(o.yaw), math.sin(o.yaw)
    return Pose2D(o.x + c * x - s * y, o.y + s * x + c * y)


START, GOAL = Pose2D(1.0, 1.0), Pose2D(5.0, 1.0)


def assert_path_free(costmap: Costmap, path: PlannedPath, margin: float) -> None:
    """Every waypoint and every segment, sampled at half a cell, keeps the clearance."""
    pts = path.points
    assert pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 2
    assert costmap.is_free(pts, margin).all(), "a waypoint is not free"
    step = costmap.resolution / 2.0
    for a, b in zip(pts[:-1], pts[1:], strict=True):
        n = max(2, math.ceil(np.linalg.norm(b - a) / step) + 1)
        samples = a + np.linspace(0.0, 1.0, n)[:, None] * (b - a)
        free = costmap.is_free(samples, margin)
        assert free.all(), f"segment {a} -> {b} leaves free space at {samples[~free][0]}"


def assert_joins(path: PlannedPath, start: Pose2D, goal: Pose2D) -> None:
    np.testing.assert_allclose(path.points[0], start.xy, atol=1e-9)
    np.testing.assert_allclose(path.points[-1], goal.xy, atol=1e-9)


def reference_length(costmap: Costmap, start: Pose2D, goal: Pose2D) -> float:
    """The shortest smoothed grid path: the length reference."""
    return GridAstarPlanner(GridAstarConfig(cost_weight=0.0)).plan(costmap, start, goal).length


@pytest.fixture(scope="module")
def room() -> Costmap:
    return room_with_door()


# --------------------------------------------------------------------------- config


def test_ompl_config_defaults_and_registry() -> None:
    cfg = OmplPlannerConfig()
    assert (cfg.type, cfg.planner, cfg.iterations, cfg.simplify, cfg.clearance) == (
        "ompl",
        "RRTConnect",
        20000,
        True,
        0.05,
    )
    assert cfg.time_limit == 5.0 and cfg.cost_weight == 1.0
    assert registry.get("global_planner", "ompl") is OmplPlanner
    assert registry.get("global_planner", "grid_astar") is GridAstarPlanner
    assert OmplPlanner.Config is OmplPlannerConfig and GridAstarPlanner.Config is GridAstarConfig
    assert isinstance(registry.create("global_planner", GridAstarConfig()), GridAstarPlanner)
    for name in [
        "RRTConnect",
        "RRT",
        "RRTstar",
        "PRMstar",
        "BITstar",
        "InformedRRTstar",
        "KPIECE1",
    ]:
        assert OmplPlannerConfig(planner=name).planner == name


def test_unknown_planner_is_a_validation_error_naming_it() -> None:
    with pytest.raises(ValidationError) as err:
        OmplPlannerConfig(planner="RRTfast")
    text = str(err.value)
    assert "RRTfast" in text and "unknown planner" in text
    assert "RRTConnect" in text and "BITstar" in text  # lists valid names


@pytest.mark.parametrize(
    "kwargs",
    [{"time_limit": 0.0}, {"clearance": -0.1}, {"bogus": 1}, {"type": "grid_astar"}],
)
def test_ompl_config_rejects_bad_values(kwargs: dict) -> None:
    with pytest.raises(ValidationError):
        OmplPlannerConfig(**kwargs)


def test_grid_config() -> None:
    cfg = GridAstarConfig()
    assert cfg.type == "grid_astar" and cfg.smooth and cfg.cost_weight > 0
    with pytest.raises(ValidationError):
        GridAstarConfig(cost_weight=-1.0)
    with pytest.raises(ValidationError):
        GridAstarConfig(connectivity=4)


# --------------------------------------------------------------------------- the door room


PLANNERS = [
    pytest.param(lambda: CostGridPlanner(CostGridConfig()), 0.05, id="cost_grid"),
    pytest.param(lambda: OmplPlanner(OmplPlannerConfig()), 0.05, id="ompl-RRTConnect"),
    pytest.param(lambda: GridAstarPlanner(GridAstarConfig()), 0.05, id="grid_astar"),
    pytest.param(
        lambda: GridAstarPlanner(GridAstarConfig(smooth=False, connectivity=8, cost_weight=0)),
        0.05,
        id="grid_astar-8-raw",
    ),
    pytest.param(
        lambda: OmplPlanner(OmplPlannerConfig(clearance=0.15, simplify=False)),
        0.15,
        id="ompl-raw-wide",
    ),
]


@pytest.mark.parametrize(("make", "margin"), PLANNERS)
def test_path_through_the_door_is_free(room: Costmap, make, margin: float) -> None:
    path = make().plan(room, START, GOAL, seed=3)
    assert_joins(path, START, GOAL)
    assert_path_free(room, path, margin)
    assert path.length > 5.0  # went round through the door, not through the wall


@pytest.mark.parametrize(("make", "margin"), PLANNERS)
def test_straight_line_when_visible(room: Costmap, make, margin: float) -> None:
    path = make().plan(room, Pose2D(0.5, 0.5), Pose2D(2.5, 3.5))
    np.testing.assert_allclose(path.points, [[0.5, 0.5], [2.5, 3.5]])


@pytest.mark.parametrize(
    ("start", "goal", "message"),
    [
        (Pose2D(3.0, 1.0), GOAL, "start (3.00, 1.00) is not free"),  # in the wall
        (START, Pose2D(3.0, 2.0), "goal (3.00, 2.00) is not free"),
        (START, Pose2D(5.95, 1.0), "goal (5.95, 1.00) is not free"),  # inside the margin
        (START, Pose2D(7.0, 1.0), "goal (7.00, 1.00) is outside the map"),
        (Pose2D(-1.0, 1.0), GOAL, "start (-1.00, 1.00) is outside the map"),
    ],
)
@pytest.mark.parametrize("kind", ["ompl", "grid", "cost_grid"])
def test_blocked_endpoints_raise(room: Costmap, start, goal, message: str, kind: str) -> None:
    planner = {
        "ompl": lambda: OmplPlanner(OmplPlannerConfig()),
        "grid": lambda: GridAstarPlanner(GridAstarConfig()),
        "cost_grid": lambda: CostGridPlanner(CostGridConfig()),
    }[kind]()
    with pytest.raises(PlanningError, match=message.replace("(", r"\(").replace(")", r"\)")):
        planner.plan(room, start, goal)


@pytest.mark.parametrize(
    "planner",
    [
        OmplPlanner(OmplPlannerConfig(time_limit=0.2)),
        OmplPlanner(OmplPlannerConfig(planner="BITstar", time_limit=0.2)),
        GridAstarPlanner(GridAstarConfig()),
        CostGridPlanner(CostGridConfig()),
    ],
    ids=["RRTConnect", "BITstar", "grid_astar", "cost_grid"],
)
def test_no_door_no_path(planner) -> None:
    closed = room_with_door(door=None)
    with pytest.raises(PlanningError, match="no path"):
        planner.plan(closed, START, GOAL)


@pytest.mark.parametrize("name", OPTIMISING)
def test_optimising_planners(room: Costmap, name: str) -> None:
    """They stop on the cost threshold (a multiple of the cost cost_grid's path would
    have under the same objective), before their iteration budget is spent."""
    cfg = OmplPlannerConfig(planner=name, time_limit=5.0)
    planner = OmplPlanner(cfg)
    path = planner.plan(room, START, GOAL, seed=1)
    assert_joins(path, START, GOAL)
    assert_path_free(room, path, 0.05)
    assert path.length <= 1.10 * reference_length(room, START, GOAL)
    diag = planner.diagnostics()
    assert diag["met_threshold"] == 1.0
    assert diag["cost"] <= cfg.cost_threshold * diag["reference_cost"] + 1e-9
    if name not in THREADED_PLANNERS:  # (PRMstar runs on the clock, not on a count)
        assert 0 < diag["iterations"] < cfg.iterations


@pytest.mark.parametrize(
    "name",
    [
        pytest.param(n, marks=pytest.mark.slow) if n in ("FMT", "BFMT") else n
        for n in available_planners()
        if n not in OPTIMISING
    ],
)
def test_other_planners(room: Costmap, name: str) -> None:
    """Every other planner the installed OMPL binds plans (FMT and BFMT cost every
    neighbour pair through the Python objective: seconds, hence slow)."""
    path = OmplPlanner(OmplPlannerConfig(planner=name, time_limit=10.0)).plan(room, START, GOAL)
    assert_joins(path, START, GOAL)
    assert_path_free(room, path, 0.05)


def test_every_bound_planner_is_selectable() -> None:
    """The planners the bindings expose, exactly: the global planning page's list."""
    assert set(available_planners()) >= {
        "AORRTC", "BFMT", "BITstar", "BKPIECE1", "FMT", "InformedRRTstar", "KPIECE1",
        "LBKPIECE1", "PRM", "PRMstar", "RRT", "RRTConnect", "RRTstar", "SORRTstar",
    }  # fmt: skip
    for name in available_planners():
        assert OmplPlannerConfig(planner=name).planner == name
    page = (Path(__file__).resolve().parents[1] / "docs" / "global-planning.md").read_text()
    for name in available_planners():
        assert f"`{name}`" in page, f"docs/global-planning.md does not list {name}"


def test_ompl_plans_are_ompls_not_the_grid_search(room: Costmap) -> None:
    """An OMPL plan is what OMPL planned: it differs from cost_grid's path, and planners
    differ from each other."""
    grid = CostGridPlanner(CostGridConfig()).plan(room, START, GOAL)
    lengths = {round(grid.length, 4)}
    for name in ("RRTConnect", "RRTstar", "BITstar"):
        path = OmplPlanner(OmplPlannerConfig(planner=name)).plan(room, START, GOAL, seed=2)
        lengths.add(round(path.length, 4))
    assert len(lengths) == 4


def path_clearance(costmap: Costmap, path: PlannedPath) -> float:
    """The least obstacle distance along the path, sampled every half cell."""
    samples = []
    for a, b in zip(path.points[:-1], path.points[1:], strict=True):
        n = max(2, math.ceil(np.linalg.norm(b - a) / (costmap.resolution / 2)) + 1)
        samples.append(a + np.linspace(0.0, 1.0, n)[:, None] * (b - a))
    return float(costmap.clearance(np.concatenate(samples)).min())


@pytest.mark.parametrize("name", ["RRTstar", "BITstar"])
def test_the_inflation_cost_reaches_ompl_through_its_objective(room: Costmap, name: str) -> None:
    """With the costmap's cost in the objective the path keeps to the middle of the door;
    with ``cost_weight: 0`` (path length) it grazes the door's edge."""
    plain = OmplPlanner(OmplPlannerConfig(planner=name, cost_weight=0.0))
    costly = OmplPlanner(OmplPlannerConfig(planner=name, cost_weight=5.0))
    near = path_clearance(room, plain.plan(room, START, GOAL, seed=4))
    far = path_clearance(room, costly.plan(room, START, GOAL, seed=4))
    assert near < ROBOT_RADIUS + 0.05 + 0.1  # the shortest way hugs the corner
    assert far > near + 0.1


def test_the_simplifier_applies_the_objective(room: Costmap) -> None:
    """OMPL's simplifier shortens RRTConnect's raw path and never makes it costlier."""
    raw = OmplPlanner(OmplPlannerConfig(simplify=False))
    simple = OmplPlanner(OmplPlannerConfig())
    for seed in range(3):
        a = raw.plan(room, START, GOAL, seed=seed)
        b = simple.plan(room, START, GOAL, seed=seed)
        assert simple.diagnostics()["cost"] <= raw.diagnostics()["cost"] + 1e-9
        assert b.length < a.length


def test_rrtconnect_length_close_to_grid(room: Costmap) -> None:
    ref = GridAstarPlanner(GridAstarConfig()).plan(room, START, GOAL).length
    planner = OmplPlanner(OmplPlannerConfig(planner="RRTConnect", simplify=True))
    for seed in range(5):
        assert planner.plan(room, START, GOAL, seed=seed).length <= 1.15 * ref


@pytest.mark.parametrize(
    "config",
    [
        OmplPlannerConfig(),
        OmplPlannerConfig(simplify=False),
        pytest.param(OmplPlannerConfig(planner="BITstar"), marks=pytest.mark.slow),  # 10 s
        OmplPlannerConfig(planner="RRTstar", time_limit=2.0),
    ],
    ids=["RRTConnect", "RRTConnect-raw", "BITstar", "RRTstar"],
)
def test_same_seed_same_path(room: Costmap, config: OmplPlannerConfig) -> None:
    planner = OmplPlanner(config)
    first = planner.plan(room, START, GOAL, seed=11)
    planner.plan(room, GOAL, START, seed=5)  # unrelated sampling in between
    again = OmplPlanner(config).plan(room, START, GOAL, seed=11)
    np.testing.assert_array_equal(first.points, again.points)


def test_seed_changes_the_samples(room: Costmap) -> None:
    planner = OmplPlanner(OmplPlannerConfig(simplify=False))
    paths = {planner.plan(room, START, GOAL, seed=s).points.tobytes() for s in range(4)}
    assert len(paths) > 1


def test_grid_astar_keeps_to_the_middle(room: Costmap) -> None:
    """Inflation cost pushes the grid path away from the walls it would otherwise hug."""
    hugging = GridAstarPlanner(GridAstarConfig(cost_weight=0.0)).plan(room, START, GOAL)
    centred = GridAstarPlanner(GridAstarConfig(cost_weight=1.0)).plan(room, START, GOAL)
    assert_path_free(room, centred, 0.05)

    def min_clearance(path: PlannedPath) -> float:
        pts = path.points
        samples = np.concatenate(
            [
                a + np.linspace(0, 1, 50)[:, None] * (b - a)
                for a, b in zip(pts[:-1], pts[1:], strict=True)
            ]
        )
        return float(room.clearance(samples).min())

    assert min_clearance(centred) > min_clearance(hugging) + 0.1
    assert centred.length < 1.1 * hugging.length


def test_grid_astar_crosses_a_400x400_zigzag() -> None:
    data = np.full((400, 400), FREE, dtype=np.int8)
    data[:2, :] = data[-2:, :] = data[:, :2] = data[:, -2:] = OCCUPIED
    data[100:102, :300] = data[200:202, 100:] = data[300:302, :300] = OCCUPIED  # a zigzag
    costmap = Costmap.from_grid(OccupancyGrid(data, RES, Pose2D(0, 0)), ROBOT_RADIUS, COSTMAP)
    planner = GridAstarPlanner(GridAstarConfig())
    path = planner.plan(costmap, Pose2D(1.0, 1.0), Pose2D(19.0, 19.0))
    assert_path_free(costmap, path, 0.05)
    assert path.length > 40.0  # the zigzag: three 15 m crossings


def test_rotated_map_origin() -> None:
    """A map whose origin is rotated: planning happens in the grid frame."""
    costmap = room_with_door(yaw=0.6)
    start, goal = to_world(costmap, 1.0, 1.0), to_world(costmap, 5.0, 1.0)
    for planner in (
        OmplPlanner(OmplPlannerConfig()),
        GridAstarPlanner(GridAstarConfig()),
        CostGridPlanner(CostGridConfig()),
    ):
        path = planner.plan(costmap, start, goal)
        assert_joins(path, start, goal)
        assert_path_free(costmap, path, 0.05)


def test_segment_traversal_covers_dense_samples() -> None:
    """Every cell a densely sampled segment touches is among the cells checked, by the
    single-segment walk and by the batched one the smoother uses."""
    space = FreeSpace(room_with_door(), 0.0)
    rng = np.random.default_rng(0)
    for _ in range(300):
        a, b = rng.uniform(0.1, [5.9, 3.9], size=(2, 2))
        if rng.random() < 0.3:  # axis-aligned
            k = rng.integers(2)
            b[k] = a[k]
        if rng.random() < 0.3:  # on grid lines and through cell corners
            a, b = np.round(a / RES) * RES, np.round(b / RES) * RES
        cells = set(space.segment_cells(*a, *b).tolist())
        t = np.linspace(0.0, 1.0, 4000)[:, None]
        pts = a + t * (b - a)
        dense = np.floor(pts[:, 1] / RES).astype(int) * space.width + np.floor(
            pts[:, 0] / RES
        ).astype(int)
        assert set(dense.tolist()) <= cells
        batch, mask, inside = segments_cells(space, a[None], b[None])  # the batched walk too
        assert inside[0] and set(dense.tolist()) <= set(batch[0][mask[0]].tolist())
    assert space.segment_cells(-0.1, 1.0, 1.0, 1.0) is None


def test_no_ompl_leaks_or_log_lines() -> None:
    """OMPL objects die inside plan(): no nanobind leak report, no OMPL chatter."""
    code = (
        "from tests.test_global_planners import room_with_door, START, GOAL\n"
        "from agv_mission.planners.ompl_planner import OmplPlanner, OmplPlannerConfig\n"
        "room = room_with_door()\n"
        "for name in ('RRTConnect', 'BITstar', 'PRMstar'):\n"
        "    for seed in range(2):\n"
        "        OmplPlanner(OmplPlannerConfig(planner=name, time_limit=0.3)).plan(room, START, GOAL, seed)\n"
        "print('ok')\n"
    )
    root = Path(__file__).resolve().parents[1]
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"
    assert "leak" not in proc.stderr and "Error" not in proc.stderr, proc.stderr
    assert "Info" not in proc.stdout + proc.stderr


# --------------------------------------------------------------------------- real maps, worlds


def ros_costmap(name: str) -> Costmap:
    from agv_mission.maps.ros_map import load_ros_map

    return Costmap.from_grid(load_ros_map(ROS_MAPS / name / "map.yaml"), ROBOT_RADIUS, COSTMAP)


def legs(waypoints: list[Pose2D]) -> list[tuple[Pose2D, Pose2D]]:
    """Consecutive pairs of a closed tour."""
    return list(zip(waypoints, waypoints[1:] + waypoints[:1], strict=True))


def patrol(costmap: Costmap, waypoints: list[Pose2D], planner, seed: int = 0) -> list[PlannedPath]:
    paths = []
    for i, (a, b) in enumerate(legs(waypoints)):
        path = planner.plan(costmap, a, b, seed=seed + i)
        assert_joins(path, a, b)
        assert_path_free(costmap, path, 0.05)
        paths.append(path)
    return paths


TB3_PATROL = [Pose2D(-2.0, -0.5), Pose2D(1.13, -1.6), Pose2D(0.13, 1.93)]
# Across the rooms of the real aws small house (living room spawn, bedroom, kitchen, ...).
HOUSE_TOUR = [Pose2D(3.83, -1.23), Pose2D(-8.0, 0.0), Pose2D(7.0, -3.0), Pose2D(-6.0, -4.0),
              Pose2D(4.0, 3.0), Pose2D(-8.5, -4.5), Pose2D(0.0, -4.0)]  # fmt: skip

MAP_PLANNERS = [
    pytest.param(lambda: CostGridPlanner(CostGridConfig()), id="cost_grid"),
    pytest.param(lambda: OmplPlanner(OmplPlannerConfig()), id="RRTConnect"),
    pytest.param(lambda: OmplPlanner(OmplPlannerConfig(planner="BITstar")), id="BITstar"),
    pytest.param(lambda: GridAstarPlanner(GridAstarConfig()), id="grid_astar"),
]


@pytest.mark.parametrize("make", MAP_PLANNERS)
def test_turtlebot3_world_ros_map_patrol(make) -> None:
    costmap = ros_costmap("turtlebot3_world")
    paths = patrol(costmap, TB3_PATROL, make())
    for path, (a, b) in zip(paths, legs(TB3_PATROL), strict=True):
        assert path.length >= a.distance_to(b) - 1e-9


@pytest.mark.parametrize("make", MAP_PLANNERS)
def test_aws_small_house_ros_map_tour(make) -> None:
    costmap = ros_costmap("aws_small_house")
    paths = patrol(costmap, HOUSE_TOUR, make())
    ref = [reference_length(costmap, a, b) for a, b in legs(HOUSE_TOUR)]
    ratios = np.array([p.length for p in paths]) / np.array(ref)
    assert ratios.min() > 0.97  # the reference is (nearly) the shortest path
    assert np.median(ratios) < 1.15


@pytest.mark.parametrize("world_name", ["turtlebot3_world", "small_house"])
@pytest.mark.parametrize("make", MAP_PLANNERS)
def test_builtin_worlds_room_to_room(world_name: str, make) -> None:
    from agv_mission.maps.builtin_worlds import BUILTIN_WORLDS

    world = BUILTIN_WORLDS[world_name]()
    costmap = Costmap.from_grid(world.map, ROBOT_RADIUS, COSTMAP)
    anchors = [world.spawn] + [r.anchor for r in world.rooms.values() if r.anchor is not None]
    anchors = [a for i, a in enumerate(anchors) if a not in anchors[:i]]
    assert len(anchors) >= 3
    patrol(costmap, anchors, make())


def test_the_watchdog_runs_on_the_planning_thread_s_cpu_time() -> None:
    """Time the planning thread spends not running (a loaded machine, a thread holding
    the interpreter) does not bring the watchdog closer: the same plan under load."""
    import time

    from agv_mission.planners.ompl_budget import IterationBudget, watchdog_clock

    clock = watchdog_clock("RRTConnect")
    budget = IterationBudget(10**9, clock() + 0.05, clock)
    time.sleep(0.2)  # waiting, as a thread does while others run
    assert not budget()
    wall = watchdog_clock("PRM")  # PRM grows its roadmap in threads of its own: the wall clock
    assert IterationBudget(10**9, wall() - 1e-9, wall)()
