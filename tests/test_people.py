"""People: the crowd (ORCA through pyrvo on the real built-in maps), the ``people:`` schema
and its resolution against a map, HuNavSim's metrics, their expectations and the
``person_near`` condition."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from py_trees.common import Status
from pydantic import TypeAdapter, ValidationError

from agv_mission.bags.writer import PEOPLE_PERIOD
from agv_mission.behaviors.check import sample_context
from agv_mission.behaviors.conditions import PersonNear
from agv_mission.maps.builtin_worlds import small_house, warehouse
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.people_resolution import resolve_people
from agv_mission.missions.load.schema.expect import Expectations
from agv_mission.missions.load.schema.people import MAX_PEOPLE, People, PeopleSpec
from agv_mission.missions.report.expectations import check
from agv_mission.missions.run.people_metrics import people_metrics
from agv_mission.missions.run.runner import run_mission
from agv_mission.world.crowd import DECISION_PERIOD, Crowd
from agv_mission.world.people_groups import PeopleGroup
from agv_mission.world.walkable import clearance
from cli_in_process import agv as agv_here

WAREHOUSE = warehouse()
HOUSE = small_house()
WHOLE_WAREHOUSE = ((-14.9, -24.9), (14.9, -24.9), (14.9, 24.9), (-14.9, 24.9))


def _walk(crowd: Crowd, steps: int, robots: np.ndarray | None = None) -> np.ndarray:
    """Positions after each step, shape (steps, n, 2); NaN while a person is absent."""
    out = np.full((steps, len(crowd.ids), 2), np.nan)
    for k in range(steps):
        crowd.step(0.1, robots)
        out[k, crowd.active] = crowd.positions[crowd.active]
    return out


def _digest(positions: np.ndarray) -> str:
    return hashlib.sha256(np.round(positions, 9).tobytes()).hexdigest()


def _wall_gap(grid, positions: np.ndarray, radii: np.ndarray) -> float:
    """The smallest distance from a body's edge to a wall over all steps (negative: in it)."""
    room = clearance(grid)
    flat = positions.reshape(-1, 2)
    ok = ~np.isnan(flat[:, 0])
    rows, cols = grid.world_to_cell(flat[ok])
    gaps = room[rows, cols] - np.tile(radii, len(positions))[ok]
    return float(gaps.min())


def test_fifty_people_wander_the_warehouse_off_the_walls_and_apart() -> None:
    crowd = Crowd(
        [PeopleGroup(count=50, behaviour="wander", area=WHOLE_WAREHOUSE)],
        WAREHOUSE.map,
        np.random.default_rng(3),
    )
    walked = _walk(crowd, 300)
    assert crowd.active.all()
    # they walk at about their preferred speed, and go places
    assert 0.8 < float(np.mean(np.hypot(*crowd.velocities.T))) < 1.5
    assert float(np.median(np.hypot(*(walked[-1] - walked[0]).T))) > 5.0
    # never through (nor into) a wall: the map's cells are 5 cm, so allow half of one
    assert _wall_gap(WAREHOUSE.map, walked, crowd.radii) > -0.03
    # and not through each other: ORCA keeps bodies apart (a couple of cm of give)
    d = np.hypot(*(walked[:, :, None, :] - walked[:, None, :, :]).transpose(3, 0, 1, 2))
    d[:, np.arange(50), np.arange(50)] = np.inf
    assert float(d.min()) > 2 * 0.25 - 0.05


def test_people_in_the_house_stay_in_free_space_through_doors() -> None:
    """Wanderers of the whole house pass its doors between rooms, never its walls."""
    house = ((-9.3, -5.3), (9.3, -5.3), (9.3, 5.3), (-9.3, 5.3))
    crowd = Crowd(
        [PeopleGroup(count=12, behaviour="wander", area=house, speed=1.4)],
        HOUSE.map,
        np.random.default_rng(11),
    )
    walked = _walk(crowd, 600)
    assert _wall_gap(HOUSE.map, walked, crowd.radii) > -0.03
    rooms_seen = set()
    for label, room in HOUSE.rooms.items():
        inside = room.contains_points(walked.reshape(-1, 2))
        if inside.any():
            rooms_seen.add(label)
    assert len(rooms_seen) >= 3  # they get about, not stuck in the room they started in


def test_same_seed_same_walks_other_seed_other_walks() -> None:
    def run(seed: int) -> str:
        crowd = Crowd(
            [
                PeopleGroup(count=20, behaviour="wander", area=WHOLE_WAREHOUSE),
                PeopleGroup(count=2, behaviour="route", route=((-12.0, 0.0), (12.0, 0.0))),
            ],
            WAREHOUSE.map,
            np.random.default_rng(seed),
        )
        robots = np.array([[0.0, -21.0, 0.4, 0.0, 0.2]])
        return _digest(_walk(crowd, 150, robots))

    assert run(5) == run(5)
    assert run(5) != run(6)


def test_same_seed_same_walks_in_another_process() -> None:
    code = (
        "import hashlib, numpy as np\n"
        "from agv_mission.maps.builtin_worlds import small_house\n"
        "from agv_mission.world.crowd import Crowd\n"
        "from agv_mission.world.people_groups import PeopleGroup\n"
        "area = ((-2.3, -5.3), (4.6, -5.3), (4.6, 5.3), (-2.3, 5.3))\n"
        "c = Crowd([PeopleGroup(count=8, behaviour='wander', area=area)], small_house().map,"
        " np.random.default_rng(9))\n"
        "out = []\n"
        "for _ in range(100):\n"
        "    c.step(0.1, np.array([[1.0, 0.0, 0.0, 0.0, 0.2]]))\n"
        "    out.append(c.positions.copy())\n"
        "print(hashlib.sha256(np.round(np.array(out), 9).tobytes()).hexdigest())\n"
    )

    def digest() -> str:
        done = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        )
        return done.stdout.strip()

    first = digest()
    assert len(first) == 64 and first == digest()


def test_a_person_walking_at_a_robot_goes_round_it() -> None:
    """Robots are agents of the crowd: a person whose route runs through a robot standing
    in the cross aisle steps round it and walks on."""
    crowd = Crowd(
        [PeopleGroup(count=1, behaviour="route", route=((-8.0, 0.0), (8.0, 0.0)))],
        WAREHOUSE.map,
        np.random.default_rng(0),
    )
    robot = np.array([[0.0, 0.0, 0.0, 0.0, 0.2]])
    walked = _walk(crowd, 150, robot)[:, 0, :]
    gap = np.hypot(*walked.T) - 0.2 - 0.25
    assert float(gap.min()) > 0.05  # never touched it
    assert float(walked[:, 0].max()) > 6.0  # and got past
    assert float(np.abs(walked[:, 1]).max()) > 0.2  # by stepping aside
    # without the robot, the same person walks the straight line
    alone = Crowd(
        [PeopleGroup(count=1, behaviour="route", route=((-8.0, 0.0), (8.0, 0.0)))],
        WAREHOUSE.map,
        np.random.default_rng(0),
    )
    assert float(np.abs(_walk(alone, 150)[:, 0, 1]).max()) < 0.1


def test_a_route_loops_and_people_spread_along_it() -> None:
    route = ((-10.0, 0.0), (10.0, 0.0))
    crowd = Crowd(
        [PeopleGroup(count=2, behaviour="route", route=route, speed=1.5)],
        WAREHOUSE.map,
        np.random.default_rng(0),
    )
    assert np.allclose(crowd.positions, [[-10.0, 0.0], [10.0, 0.0]], atol=0.15)
    walked = _walk(crowd, 400)  # 40 s at 1.5 m/s: 60 m, end to end and back
    first = walked[:, 0, 0]
    assert first.max() > 9.0 and first[-100:].min() < first.max() - 5.0  # there and back


def test_people_enter_at_their_start_time() -> None:
    crowd = Crowd(
        [
            PeopleGroup(
                count=3, behaviour="wander", area=HOUSE.rooms["kitchen"].polygon, start_time=1.0
            )
        ],  # fmt: skip
        HOUSE.map,
        np.random.default_rng(1),
    )
    walked = _walk(crowd, 20)
    assert np.isnan(walked[:10]).all()  # t = 0.1 .. 1.0: not yet in (entered at step 10)
    assert not np.isnan(walked[12:]).any()


def test_people_decide_every_other_step_and_walk_every_step() -> None:
    """ORCA decides every DECISION_PERIOD (two control steps): in between, a person walks
    the decided velocity, a step at a time, and the robots are not looked at."""
    crowd = Crowd(
        [PeopleGroup(count=1, behaviour="route", route=((-8.0, 0.0), (8.0, 0.0)))],
        WAREHOUSE.map,
        np.random.default_rng(0),
    )
    assert crowd.decision_period == pytest.approx(0.2) and crowd.deciding
    walked = _walk(crowd, 41)[:, 0, :]  # decisions at steps 1, 3, 5, ...
    moves = np.diff(walked, axis=0)  # moves[2k + 1], moves[2k + 2]: one decision's steps
    assert (np.hypot(*moves[4:].T) > 0.05).all()  # walks every control step
    assert np.allclose(moves[1:-1:2], moves[2::2])  # the same velocity within a decision
    assert not np.allclose(moves[1:-1:2], moves[3::2])  # decisions differ (the noise at least)
    crowd.step(0.1)  # the second step of a decision needs no robots
    assert crowd.deciding


def test_a_notched_obstacle_goes_to_orca_as_its_hull_an_l_shape_does_not() -> None:
    """A rack with uprights standing 0.1 m out of its face reaches ORCA as its hull (4
    corners, not one per notch); an L-shaped piece of furniture keeps its shape."""
    import shapely

    from agv_mission.world.walkable import _obstacle

    rack = shapely.Polygon(
        [(0, 0), (0.1, 0), (0.1, 0.1), (1.0, 0.1), (1.0, 0.0), (1.1, 0), (1.1, 3), (0, 3)]
    )
    hole = shapely.orient_polygons(rack).exterior.reverse()  # a hole of the free space: CW
    corners = _obstacle(hole)
    assert len(corners) == 4
    assert shapely.LinearRing(corners).is_ccw and shapely.Polygon(corners).equals(rack.convex_hull)
    ell = shapely.Polygon([(0, 0), (2, 0), (2, 0.5), (0.5, 0.5), (0.5, 2), (0, 2)])
    corners = _obstacle(shapely.orient_polygons(ell).exterior.reverse())
    assert len(corners) == 6 and shapely.LinearRing(corners).is_ccw
    assert shapely.Polygon(corners).equals(ell)


def test_beams_on_people_are_every_beam_ending_on_someone() -> None:
    """The lidar filter looks only at the beams pointing at someone: the same beams as
    checking every beam's end against every person, on scans of every kind."""
    from agv_mission.geometry import Pose2D
    from agv_mission.navigation.scan_filter import PERSON_TOLERANCE, beams_on_people
    from agv_mission.sensor_msgs import LaserScan

    rng = np.random.default_rng(3)
    hits = 0
    for _ in range(300):
        n = int(rng.choice([90, 360, 1000]))
        fov = float(rng.choice([2 * np.pi, 1.5 * np.pi]))
        angle_min = float(rng.choice([0.0, -fov / 2]))
        pose = Pose2D(*rng.uniform(-2, 2, 2), rng.uniform(-7, 7))
        count = int(rng.integers(1, 5))
        people = np.column_stack(
            [
                rng.uniform(-5, 5, (count, 2)),
                rng.uniform(0.1, 0.4, count),
                rng.uniform(-1.0, 1.0, (count, 2)),
                rng.choice([0.0, 0.4, 1.5], count),  # s standing
            ]
        )
        angles = angle_min + fov / n * np.arange(n) + pose.yaw
        ranges = rng.uniform(0.2, 4.0, n)
        for x, y, r, *_ in people:  # beams that see someone end on their body
            d = np.hypot(x - pose.x, y - pose.y)
            off = np.abs(
                (angles - np.arctan2(y - pose.y, x - pose.x) + np.pi) % (2 * np.pi) - np.pi
            )
            ranges[off < np.arcsin(min(1.0, r / d))] = d - 0.8 * r
        ranges[(ranges > 3.5) | (rng.random(n) < 0.1)] = np.inf  # nothing within range
        ranges[rng.random(n) < 0.05] = np.nan
        scan = LaserScan(
            ranges=ranges.astype(np.float32),
            angle_min=angle_min,
            angle_increment=fov / n,
            range_min=0.1,
            range_max=3.5,
            time=0.0,
        )
        r64 = scan.ranges.astype(float)
        with np.errstate(invalid="ignore"):
            ex = pose.x + r64 * np.cos(scan.angles + pose.yaw)
            ey = pose.y + r64 * np.sin(scan.angles + pose.yaw)
            d2 = (ex[:, None] - people[:, 0]) ** 2 + (ey[:, None] - people[:, 1]) ** 2
            ends_on = d2 <= (people[:, 2] + PERSON_TOLERANCE) ** 2
            expected = ends_on.any(axis=1)

        mask = beams_on_people(scan, pose, people)
        if mask is None:  # nobody within the lidar's reach
            assert not expected.any()
            continue
        assert np.array_equal(mask, expected)
        hits += int(mask.sum())
    assert hits > 1000


# --- schema ------------------------------------------------------------------------------

PEOPLE = TypeAdapter(People)


def test_the_contracts_example_validates_with_its_defaults() -> None:
    groups = PEOPLE.validate_python(
        [
            {"count": 6, "area": "kitchen", "behaviour": "wander", "speed": 1.0},
            {
                "count": 2,
                "behaviour": "route",
                "route": [{"x": 1.0, "y": 2.0}, {"x": 8.0, "y": 2.0}],
                "speed": 1.3,
                "radius": 0.25,
                "start_time": 10.0,
            },
            {"area": [[0, 0], [2, 0], [2, 2]]},
        ]
    )
    assert groups[0].radius == 0.25 and groups[0].start_time == 0.0
    assert groups[2].speed == 1.2 and groups[2].behaviour == "wander" and groups[2].count == 1


@pytest.mark.parametrize(
    ("entry", "words"),
    [
        ({"count": 10**9, "area": "kitchen"}, f"less than or equal to {MAX_PEOPLE}"),
        ({"area": "kitchen", "speed": 40.0}, "less than or equal to 3"),
        ({"behaviour": "wander"}, "need an `area`"),
        ({"behaviour": "route", "route": [{"x": 0, "y": 0}]}, "at least 2 items"),
        ({"behaviour": "route", "area": "kitchen"}, "need `route`"),
        ({"area": [[0, 0], [1, 1], [0, 1], [1, 0]]}, "simple"),
        ({"area": "kitchen", "sped": 1.0}, "Extra inputs"),
        ({"area": "kitchen", "radius": float("nan")}, "finite"),
    ],
)
def test_bad_people_entries_say_what_is_wrong(entry: dict, words: str) -> None:
    with pytest.raises(ValidationError) as err:
        PeopleSpec.model_validate(entry)
    assert words in str(err.value)


def test_too_many_people_in_all_is_refused() -> None:
    with pytest.raises(ValidationError, match=f"at most {MAX_PEOPLE}"):
        PEOPLE.validate_python([{"count": 150, "area": "a"}, {"count": 60, "area": "b"}])


# --- resolving against the map --------------------------------------------------------


def _resolve(entries: list[dict]) -> tuple[list[PeopleGroup], list[tuple[tuple, str]]]:
    problems: list[tuple[tuple, str]] = []
    groups = resolve_people(
        PEOPLE.validate_python(entries),
        HOUSE.rooms,
        HOUSE.map,
        lambda where, message: problems.append((where, message)),
    )
    return groups, problems


def test_rooms_and_routes_resolve_to_the_map_frame() -> None:
    groups, problems = _resolve(
        [
            {"count": 4, "area": "kitchen"},
            {"behaviour": "route", "route": [{"x": -5.0, "y": -2.0}, {"x": 2.0, "y": -2.0}]},
        ]
    )
    assert problems == []
    assert groups[0].area == HOUSE.rooms["kitchen"].polygon and groups[0].count == 4
    assert groups[1].route == ((-5.0, -2.0), (2.0, -2.0)) and groups[1].behaviour == "route"


def test_problems_are_reported_at_their_field() -> None:
    _, problems = _resolve(
        [
            {"area": "garage"},
            {"behaviour": "route", "route": [{"x": -5.0, "y": -2.0}, {"x": -2.4, "y": -3.0}]},
            {"behaviour": "route", "route": [{"x": -5.0, "y": -2.0}, {"x": 50.0, "y": 0.0}]},
            {"count": 150, "area": [[5.0, -5.0], [6.0, -5.0], [6.0, -4.0], [5.0, -4.0]]},
        ]
    )
    where = dict(problems)
    assert "no room 'garage'" in where[("people", 0, "area")]
    assert "kitchen" in where[("people", 0, "area")]  # the rooms there are
    assert "in a wall" in where[("people", 1, "route", 1)]
    assert "off the map" in where[("people", 2, "route", 1)]
    assert "do not fit" in where[("people", 3, "count")]


def test_a_route_point_walled_off_from_the_first_is_refused() -> None:
    """A pocket of free space no door leads to (a point between the warehouse's outer
    wall and the map's edge would be unknown; a closed box is the same)."""
    grid = HOUSE.map
    data = grid.data.copy()
    rows, cols = grid.world_to_cell(np.array([[6.0, -3.0], [8.0, -1.0]]))
    data[rows[0] : rows[1], cols[0]] = 100  # a closed box in the kitchen
    data[rows[0] : rows[1], cols[1]] = 100
    data[rows[0], cols[0] : cols[1] + 1] = 100
    data[rows[1], cols[0] : cols[1] + 1] = 100
    boxed = type(grid)(data=data, resolution=grid.resolution, origin=grid.origin)
    problems: list[tuple[tuple, str]] = []
    resolve_people(
        PEOPLE.validate_python(
            [{"behaviour": "route", "route": [{"x": 2.0, "y": -2.0}, {"x": 7.0, "y": -2.0}]}]
        ),
        HOUSE.rooms,
        boxed,
        lambda where, message: problems.append((where, message)),
    )
    assert problems and problems[0][0] == ("people", 0, "route", 1)
    assert "walls are in the way" in problems[0][1]


def _near_wall(grid, xy: tuple[float, float], room: float) -> tuple[float, float]:
    """The free cell nearest ``xy`` whose room to the nearest wall is ``room`` (+-0.01 m)."""
    left = clearance(grid)
    rows, cols = np.nonzero(np.abs(left - room) <= 0.01)
    centres = grid.cell_to_world(rows, cols)
    best = centres[np.argmin(np.hypot(*(centres - np.asarray(xy)).T))]
    return float(best[0]), float(best[1])


def test_a_route_point_too_near_a_wall_is_walked_to_as_near_as_the_person_fits() -> None:
    """Picked by eye 0.22 m from a wall, for a person of radius 0.25 m: the person walks to
    the nearest point where they fit, with a warning at the point's field; only a point in a
    wall or off the map is invalid."""
    x, y = _near_wall(HOUSE.map, (-5.0, -4.0), 0.22)
    warnings: list[tuple[tuple, str]] = []
    problems: list[tuple[tuple, str]] = []
    [group] = resolve_people(
        PEOPLE.validate_python(
            [
                {
                    "behaviour": "route",
                    "radius": 0.25,
                    "route": [{"x": -5.0, "y": -2.0}, {"x": x, "y": y}],
                }
            ]
        ),
        HOUSE.rooms,
        HOUSE.map,
        lambda where, message: problems.append((where, message)),
        lambda where, message: warnings.append((where, message)),
    )
    assert problems == []
    [(where, message)] = warnings
    assert where == ("people", 0, "route", 1) and "0.22 m from a wall" in message
    moved = group.route[1]
    assert group.route[0] == (-5.0, -2.0) and moved != (x, y)
    assert np.hypot(moved[0] - x, moved[1] - y) < 0.1  # as near as they fit
    rows, cols = HOUSE.map.world_to_cell(np.array(moved))
    assert clearance(HOUSE.map)[int(rows), int(cols)] >= 0.25


def test_an_area_too_near_a_wall_is_walked_as_near_as_the_people_fit() -> None:
    x, y = _near_wall(HOUSE.map, (-5.0, -4.0), 0.15)
    square = [[x - 0.1, y - 0.1], [x + 0.1, y - 0.1], [x + 0.1, y + 0.1], [x - 0.1, y + 0.1]]
    warnings: list[tuple[tuple, str]] = []
    problems: list[tuple[tuple, str]] = []
    [group] = resolve_people(
        PEOPLE.validate_python([{"count": 1, "area": square}]),
        HOUSE.rooms,
        HOUSE.map,
        lambda where, message: problems.append((where, message)),
        lambda where, message: warnings.append((where, message)),
    )
    assert problems == [] and [w for w, _ in warnings] == [("people", 0, "area")]
    assert "as near as they fit" in warnings[0][1]
    crowd = Crowd([group], HOUSE.map, np.random.default_rng(1))
    walked = _walk(crowd, 50)
    assert _wall_gap(HOUSE.map, walked, crowd.radii) > -0.03  # they walk where they fit


def test_a_people_mission_with_a_point_near_a_wall_validates_and_runs(tmp_path: Path) -> None:
    x, y = _near_wall(HOUSE.map, (-5.0, -4.0), 0.22)
    mission = tmp_path / "near.yaml"
    mission.write_text(
        "name: near\nworld: small_house\nstart: {x: -1.5, y: -2.0, yaw: 0.0}\nseed: 2\n"
        "stack:\n  localization: {type: ground_truth}\n"
        f"people:\n  - {{behaviour: route, radius: 0.25, route: [{{x: -5.0, y: -2.0}}, {{x: {x}, y: {y}}}]}}\n"
        "tasks:\n  - {type: go_to, pose: {x: -1.0, y: -2.0, yaw: 0.0}}\n"
        f"limits: {{time: 6.0}}\noutput: {tmp_path / 'runs'}\n"
    )
    agv = str(Path(sys.executable).parent / "agv-mission")
    valid = agv_here("validate", str(mission))  # in this process; ``run`` below starts one
    assert valid.returncode == 0, valid.stdout + valid.stderr
    assert "warning" in valid.stderr and "people.0.route.1" in valid.stderr
    assert f"{mission}:8: people.0.route.1" in valid.stderr  # file, line and field
    done = subprocess.run([agv, "run", str(mission)], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "people.0.route.1" in done.stderr
    run_dir = next((tmp_path / "runs").iterdir())
    result = __import__("json").loads((run_dir / "result.json").read_text())
    assert any("people.0.route.1" in w for w in result["warnings"])
    inside = mission.read_text().replace(f"x: {x}, y: {y}", "x: -2.4, y: -3.0")  # in a wall
    mission.write_text(inside)
    bad = agv_here("validate", str(mission))
    assert bad.returncode == 2 and "in a wall" in bad.stderr


# --- metrics and expectations -----------------------------------------------------------


def test_hunavsim_metrics_from_arrays() -> None:
    t = np.round(np.arange(0.0, 10.0, 0.1), 9)
    robot = np.stack([np.minimum(t, 5.0) * 0.5, np.zeros_like(t)], axis=1)  # stops at t = 5
    people = np.full((len(t), 2, 2), np.nan)
    people[20:, 0] = [3.0, 0.0]  # appears at t = 2 where the robot will drive into it
    people[:, 1] = [0.0, 9.0]  # far away all along
    m = people_metrics(t, robot, people, 0.2, np.array([0.25, 0.25]), [(0.0, 5.0), (5.0, 9.9)])
    # the robot's centre reaches x = 2.5 at t = 5: 0.5 m from the person's centre
    assert m["min_distance"] == pytest.approx(0.5 - 0.45)
    assert m["collisions"] == 0
    # intimate (< 0.45 m edge to edge): centre gap < 0.9, robot x > 2.1, from t = 4.2
    assert m["intimate_time"] == pytest.approx(10.0 - 4.2, abs=0.11)
    assert m["personal_time"] == pytest.approx(10.0 - 2.7, abs=0.11)  # x > 1.35 from t 2.7
    assert m["time_not_moving"] == pytest.approx(5.0, abs=0.11)
    assert m["legs"][0] == {"path_length": pytest.approx(2.5), "time": 5.0}
    assert m["legs"][1]["path_length"] == pytest.approx(0.0)
    # turning on the spot from t = 7 is moving (HuNavSim: not moving is < 0.01 m/s and
    # < 0.02 rad/s)
    yaw = np.where(t > 7.0, (t - 7.0) * 0.5, 0.0)
    m = people_metrics(t, robot, people, 0.2, np.array([0.25, 0.25]), robot_yaw=yaw)
    assert m["time_not_moving"] == pytest.approx(2.0, abs=0.11)
    # driving on into the person: one contact begun, however long it lasts
    people[:, 0] = [2.6, 0.0]
    m = people_metrics(t, robot, people, 0.2, np.array([0.25, 0.25]))
    assert m["collisions"] == 1 and m["min_distance"] < 0.0


def test_metrics_without_anyone_in_the_world() -> None:
    t = np.arange(0.0, 1.0, 0.1)
    m = people_metrics(t, np.zeros((10, 2)), np.zeros((10, 0, 2)), 0.2, np.zeros(0))
    assert m["min_distance"] is None and m["personal_time"] == 0.0 and m["collisions"] == 0
    for steps in (0, 1):  # a run that ended before (or at) its first step
        m = people_metrics(np.zeros(steps), np.zeros((steps, 2)), np.full((steps, 3, 2), 9.0), 0.2,
                           np.full(3, 0.25), [(0.0, 0.0)])  # fmt: skip
        assert m["collisions"] == 0 and m["time_not_moving"] == 0.0


def test_people_expectations_read_metrics_people() -> None:
    expect = Expectations(
        people_collisions_max=0, people_min_distance_min=0.2, personal_time_max=5.0
    )
    good = {"status": "succeeded", "metrics": {"people": {
        "collisions": 0, "min_distance": 0.35, "personal_time": 2.0}}}  # fmt: skip
    assert check(expect, good) == []
    bad = {"status": "succeeded", "metrics": {"people": {
        "collisions": 2, "min_distance": 0.1, "personal_time": 7.5}}}  # fmt: skip
    failed = {f.metric: f for f in check(expect, bad)}
    assert set(failed) == {"people_collisions_max", "people_min_distance_min", "personal_time_max"}
    assert failed["people_min_distance_min"].by == pytest.approx(0.1)


# --- person_near ---------------------------------------------------------------------------


def test_person_near_measures_footprint_to_the_persons_edge() -> None:
    context = sample_context()  # a burger at (1, 1) with a real navigator
    handle = context.handle
    node = PersonNear("near", handle, distance=0.5)
    footprint = handle.navigator.costmap.robot_radius
    node.setup()
    assert node.tick_once() is None and node.status == Status.FAILURE  # nobody there
    handle.state.people = np.array([[1.0 + footprint + 0.25 + 0.6, 1.0, 0.25]])
    node.tick_once()
    assert node.status == Status.FAILURE and "nearest 0.60 m" in node.feedback_message
    handle.state.people = np.array([[5.0, 5.0, 0.25], [1.0, 1.0 + footprint + 0.25 + 0.4, 0.25]])
    node.tick_once()
    assert node.status == Status.SUCCESS


# --- /people in the bag --------------------------------------------------------------------


def test_people_markers_packed_byte_for_byte_as_rosbags_serialises_them() -> None:
    from agv_mission.bags import ros_messages as rm
    from agv_mission.bags.cdr import PeopleMarkersCdr

    packer = PeopleMarkersCdr()
    rng = np.random.default_rng(0)
    for n, t in ((3, 0.1), (3, 7.25), (5, 1234.5)):  # the same set again, then one grown
        ids = np.arange(n)
        xy = rng.uniform(-20.0, 20.0, (n, 2))
        radii = np.linspace(0.2, 0.3, n)
        expected = rm.serialize(rm.people_markers(t, ids, xy, radii), rm.MARKER_ARRAY)
        assert packer.pack(t, ids, xy, radii) == expected
    msg = rm.typestore().deserialize_cdr(packer.pack(2.0, ids, xy, radii), rm.MARKER_ARRAY)
    first = msg.markers[0]
    assert first.ns == "people" and first.type == 3 and first.scale.x == pytest.approx(0.4)
    assert (first.pose.position.x, first.pose.position.y) == tuple(xy[0])
    assert first.header.stamp.sec == 2 and first.header.frame_id == "map"


# --- runs with people ---------------------------------------------------------------------

STEP_OUT = """\
name: step-out
world: warehouse
start: {{x: -8.0, y: 0.0, yaw: 0.0}}
seed: 4
stack:
  localization: {{type: ground_truth}}
  local_planner: {{type: pure_pursuit}}
  costmap: {{obstacles: {{enabled: false}}}}
  collision_monitor: {{enabled: {enabled}}}
people:
  - {{behaviour: route, route: [{{x: -5.6, y: -0.05}}, {{x: -5.6, y: 0.0}}], start_time: 5.0,
      attentive: false}}
tasks:
  - {{type: go_to, pose: {{x: 4.0, y: 0.0, yaw: 0.0}}}}
limits: {{time: 14.0}}
"""


def test_the_monitor_stops_a_blind_robot_for_a_person_stepping_out_1_m_ahead(
    tmp_path: Path,
) -> None:
    """At t = 5 s the burger drives at its full 0.22 m/s with its front at x = -6.84 when a
    person who does not look out appears with their edge 1 m ahead and stands. Pure pursuit
    without an obstacle layer is blind to them: without the collision monitor it runs
    into them; with it, it stops short, on the raw lidar points."""
    records = {}
    for enabled in ("true", "false"):
        path = tmp_path / f"step_out_{enabled}.yaml"
        path.write_text(STEP_OUT.format(enabled=enabled))
        records[enabled] = run_mission(load_mission(path))
    on, off = records["true"], records["false"]
    at_five = on.trajectory[np.argmin(np.abs(on.trajectory[:, 0] - 5.0))]
    assert at_five[7] == pytest.approx(0.22)  # full speed when the person appears
    assert 1.0 - 0.05 < (-5.6 - 0.25) - (at_five[1] + 0.105) < 1.0 + 0.05
    assert off.metrics["people"]["collisions"] >= 1
    assert any(e["event"] == "person_collision" for e in off.events)
    assert off.metrics["collisions"] == 0  # a person is not a wall
    assert on.metrics["people"]["collisions"] == 0
    assert on.metrics["people"]["min_distance"] > 0.0
    assert on.metrics["collision_monitor"]["stop"]["activations"] >= 1


def test_a_run_with_people_writes_people_csv_the_bag_topic_and_metrics(tmp_path: Path) -> None:
    from rosbags.highlevel import AnyReader

    mission = tmp_path / "walk.yaml"
    mission.write_text(
        "name: walk\nworld: small_house\nstart: {x: -1.5, y: -2.0, yaw: 0.0}\nseed: 2\n"
        "stack:\n  localization: {type: ground_truth}\n"
        "people:\n  - {count: 3, area: livingroom}\n"
        "  - {behaviour: route, route: [{x: -5.0, y: -4.0}, {x: -5.0, y: 0.0}], start_time: 2.0}\n"
        "tasks:\n  - {type: go_to, pose: {x: 3.5, y: -2.0, yaw: 0.0}}\n"
        f"limits: {{time: 8.0}}\noutput: {tmp_path / 'runs'}\n"
    )
    done = subprocess.run(
        [str(Path(sys.executable).parent / "agv-mission"), "run", str(mission)],
        capture_output=True,
        text=True,
    )
    assert done.returncode in (0, 1), done.stderr
    run_dir = next((tmp_path / "runs").iterdir())
    rows = (run_dir / "people.csv").read_text().splitlines()
    assert rows[0] == "t,id,x,y"
    table = np.array([[float(v) for v in row.split(",")] for row in rows[1:]])
    assert set(table[:, 1].astype(int)) == {0, 1, 2, 3}
    assert table[table[:, 1] == 3, 0].min() == pytest.approx(2.0, abs=0.11)  # entered at 2 s
    inside = HOUSE.rooms["livingroom"].contains_points(table[table[:, 1] < 3][:, 2:4])
    assert inside.mean() > 0.9  # wanderers stay in their room (bodies may lean over its line)
    import json

    result = json.loads((run_dir / "result.json").read_text())
    people = result["metrics"]["people"]
    assert people["people"] == 4 and people["collisions"] == 0
    assert people["min_distance"] is not None and people["legs"]
    with AnyReader([run_dir / "bag"]) as reader:
        conns = [c for c in reader.connections if c.topic == "/people"]
        assert conns and conns[0].msgtype == "visualization_msgs/msg/MarkerArray"
        arrays = [
            (stamp * 1e-9, reader.deserialize(raw, conn.msgtype))
            for conn, stamp, raw in reader.messages(connections=conns)
        ]
    # every PEOPLE_PERIOD (the people's decisions: they walk straight in between), each
    # marker where people.csv has them then
    times = np.array([t for t, _ in arrays])
    assert np.allclose(np.diff(times), PEOPLE_PERIOD) and PEOPLE_PERIOD == DECISION_PERIOD
    assert sorted(m.id for m in arrays[-1][1].markers) == [0, 1, 2, 3]
    for t, markers in arrays:
        at = table[np.isclose(table[:, 0], t)]
        for m in markers.markers:
            row = at[at[:, 1] == m.id][0]
            assert (m.pose.position.x, m.pose.position.y) == pytest.approx(row[2:4], abs=1e-3)


def test_people_csv_rows_are_what_percent_formatting_writes(tmp_path: Path) -> None:
    """people.csv's digits are made by array arithmetic: the same bytes as formatting each
    row with "%.6f,%d,%.4f,%.4f", for people absent (NaN), negative, tiny and far."""
    from agv_mission.missions.run.people_record import write_people_csv

    rng = np.random.default_rng(4)
    for scale in (0.0001, 1.0, 40.0, 9000.0):
        steps, n = 60, 7
        t = np.arange(steps) * 0.1
        xy = rng.normal(0.0, scale, (steps, n, 2)).astype(np.float32).astype(float)
        xy[rng.random((steps, n)) < 0.2] = np.nan
        xy[3, 2] = (-0.0, 0.0)
        ids = np.arange(n) * 11
        write_people_csv(tmp_path / "people.csv", t, xy, ids)
        rows = [
            "%.6f,%d,%.4f,%.4f" % (t[k], ids[i], *xy[k, i])  # noqa: UP031 (the reference)
            for k in range(steps)
            for i in range(n)
            if not np.isnan(xy[k, i, 0])
        ]
        assert (tmp_path / "people.csv").read_text() == "t,id,x,y\n" + "".join(
            r + "\n" for r in rows
        )


def test_the_tracker_counts_how_long_each_person_has_stood(tmp_path: Path) -> None:
    """``RobotState.people``'s last column: seconds a person has been slower than
    STANDING, 0 while they walk (someone whose route is one place stands; a wanderer walks)."""
    from agv_mission.missions.run.runner import MissionRun
    from agv_mission.navigation.state import STANDING, TRACKED_PERSON

    mission = tmp_path / "still.yaml"
    mission.write_text(
        "name: still\nworld: small_house\nstart: {x: -1.5, y: -2.0, yaw: 0.0}\nseed: 2\n"
        "stack:\n  localization: {type: ground_truth}\n"
        "people:\n  - {count: 1, behaviour: route, route: [{x: 3.5, y: 3.0}, {x: 3.5, y: 3.0}]}\n"
        "  - {count: 1, area: livingroom}\n"
        "tasks:\n  - {type: wander, duration: 4.0}\nlimits: {time: 4.0}\n"
    )
    run = MissionRun(load_mission(mission), tmp_path, [])
    run.notify_start()
    seen = []
    while run.step():
        rows = run.robots[0].handle.state.people
        assert rows.shape == (2, len(TRACKED_PERSON))
        seen.append(rows.copy())
    rows = np.array(seen)
    speed = np.hypot(rows[:, :, 3], rows[:, :, 4])
    assert (rows[speed >= STANDING, 5] == 0.0).all()  # walking: not still
    assert (rows[:, 1, 5] == 0.0).mean() > 0.8  # the wanderer walks nearly all the time
    stander = rows[:, 0, 5]
    assert stander[-1] == pytest.approx(stander[10] + (len(stander) - 11) * 0.1)  # counts up
    assert stander[-1] > 3.0


def test_the_dashboards_stream_carries_the_people(tmp_path: Path) -> None:
    """The run's stream (live and ``stream.jsonl``, which the run page replays) has
    ``people`` messages: ``[id, x, y, radius]`` of everyone present."""
    import json
    from multiprocessing import Pipe

    from agv_mission.missions.run.runner import MissionRun
    from agv_mission.service.stream import STREAM_FILE, StreamObserver

    mission = tmp_path / "walk.yaml"
    mission.write_text(
        "name: walk\nworld: small_house\nstart: {x: -1.5, y: -2.0, yaw: 0.0}\nseed: 2\n"
        "stack:\n  localization: {type: ground_truth}\n"
        "people:\n  - {count: 2, area: livingroom}\n"
        "tasks:\n  - {type: go_to, pose: {x: 3.5, y: -2.0, yaw: 0.0}}\nlimits: {time: 3.0}\n"
    )
    mine, theirs = Pipe()
    stream = StreamObserver(theirs, tmp_path)
    run = MissionRun(load_mission(mission), tmp_path, [stream])
    run.notify_start()
    run.drive()
    stream.on_end(run.record())
    lines = [json.loads(line) for line in (tmp_path / STREAM_FILE).read_text().splitlines()]
    people = [m for m in lines if m["type"] == "people"]
    assert len(people) >= 5  # every 0.5 simulated s in the file
    last = people[-1]["people"]
    assert [p[0] for p in last] == [0, 1] and all(p[3] == 0.25 for p in last)
    assert all(HOUSE.rooms["livingroom"].contains(p[1], p[2]) for p in last)
    live = []
    while mine.poll():
        item = mine.recv()
        if item[0] == "msg" and item[1] == "people":
            live.append(item)
    assert live


def test_the_mpc_keeps_off_where_a_crossing_person_will_be() -> None:
    """A person 1.5 m ahead and 1.5 m to the right walks across the robot's straight path
    at 1 m/s: at 1 m/s the robot would meet them. Given the person as a moving obstacle,
    the MPC's predicted motion keeps its distance from where they will be at each stage;
    given only where they stand now, it drives straight on into that place."""
    from agv_mission.geometry import Pose2D
    from agv_mission.planners.base import VelocityLimits
    from agv_mission.planners.configs import MpcConfig
    from agv_mission.planners.mpc import MpcController

    limits = VelocityLimits(max_v=1.0, max_w=2.0, max_acc_v=2.0, max_acc_w=4.0)
    path = np.column_stack([np.linspace(0.0, 6.0, 61), np.zeros(61)])
    goal = Pose2D(6.0, 0.0, 0.0)
    person = np.array([[1.5, -1.5, 0.25, 0.0, 1.0]])  # x, y, radius, vx, vy
    here = np.array([[1.5, -1.5 + 0.25]])  # a lidar point on them now
    cfg = MpcConfig()

    def horizon(moving: np.ndarray | None) -> np.ndarray:
        ctrl = MpcController(cfg, limits, 0.105, 0.1)
        pose, v = Pose2D(0.0, 0.0, 0.0), (1.0, 0.0)
        cmd = None
        for _ in range(5):  # a few steps: the real-time iteration settles
            cmd = ctrl.compute(pose, v, path, goal, here if moving is None else np.zeros((0, 2)),
                               moving)  # fmt: skip
        assert cmd is not None and cmd.ok
        return cmd.predicted

    def closest(states: np.ndarray) -> float:
        t = np.arange(len(states)) * cfg.dt
        where = person[0, :2] + t[:, None] * person[0, 3:5]
        return float(np.min(np.hypot(*(states[:, :2] - where).T)) - 0.105 - 0.25)

    predicted_with, predicted_without = horizon(person), horizon(None)
    assert closest(predicted_without) < 0.05  # blind to where they go: into them
    assert closest(predicted_with) > 0.05  # keeps off their predicted place (0.13 m)


def test_the_costmap_leaves_out_people_passing_by_but_not_people_standing() -> None:
    """Someone walking by, or pausing less than STILL_TIME, is the controller's to avoid
    (their lidar returns are not marked); someone who has stood that long is marked as
    their body grown by the controller's margin (a plan it can follow), and unmarked once
    they walk on."""
    from agv_mission.geometry import Pose2D
    from agv_mission.navigation.scan_filter import PERSON_TOLERANCE, STILL_TIME
    from agv_mission.sensor_msgs import LaserScan

    navigator = sample_context().handle.navigator  # a real navigator in a 4 m room
    # the MPC's people_margin; a controller without one: the tracker's tolerance
    margin = getattr(navigator.local_planner.config, "people_margin", PERSON_TOLERANCE)
    layer = navigator.layer
    pose = Pose2D(1.0, 1.0, 0.0)

    def scan(ahead: float) -> LaserScan:
        ranges = np.full(360, np.inf, dtype=np.float32)
        ranges[0] = ahead
        return LaserScan(ranges, 0.0, 2 * np.pi / 360, 0.12, 3.5, 0.0)

    walking = np.array([[2.25, 1.0, 0.25, 0.0, 1.0, 0.0]])  # x, y, radius, vx, vy, still
    navigator.observe(pose, scan(1.0), walking)  # the return at (2, 1) is on them
    assert not layer.marks.any()
    pausing = walking.copy()
    pausing[0, 3:] = (0.0, 0.0, STILL_TIME - 0.1)
    navigator.observe(pose, scan(1.0), pausing)
    assert not layer.marks.any()
    standing = walking.copy()
    standing[0, 3:] = (0.0, 0.0, STILL_TIME)
    navigator.observe(pose, scan(1.0), standing)
    rows, cols = np.nonzero(layer.marks)
    centres = layer.static.grid.cell_to_world(rows, cols)
    reach = np.hypot(centres[:, 0] - 2.25, centres[:, 1] - 1.0)
    assert reach.max() <= 0.25 + margin and reach.max() > 0.25 + margin - 0.05
    assert len(rows) > 0.8 * np.pi * (0.25 + margin) ** 2 / 0.05**2  # the disc, at 5 cm
    assert navigator.costmap.clearance(np.array([[2.25 - 0.25 - margin - 0.05, 1.0]]))[0] < 0.06
    navigator.observe(pose, scan(1.0), standing)  # the beam through their margin keeps it
    assert layer.marks.sum() == len(rows)
    navigator.observe(pose, scan(np.inf), walking)  # walked on: unmarked
    assert not layer.marks.any()
    navigator.observe(pose, scan(1.0), None)  # not a person: marked as before
    assert layer.marks.sum() == 1


def test_a_run_with_people_is_reproduced_from_its_seed(tmp_path: Path) -> None:
    mission = tmp_path / "again.yaml"
    mission.write_text(
        "name: again\nworld: small_house\nstart: {x: -1.5, y: -2.0, yaw: 0.0}\nseed: 5\n"
        "people:\n  - {count: 4, area: livingroom}\n"
        "tasks:\n  - {type: go_to, pose: {x: 3.5, y: -2.0, yaw: 0.0}}\nlimits: {time: 6.0}\n"
    )
    first, second = (run_mission(load_mission(mission)) for _ in range(2))
    assert np.array_equal(first.trajectory, second.trajectory)
    assert np.array_equal(first.people.xy, second.people.xy, equal_nan=True)
    other = mission.read_text().replace("seed: 5", "seed: 6")
    mission.write_text(other)
    third = run_mission(load_mission(mission))
    assert not np.array_equal(first.people.xy, third.people.xy, equal_nan=True)


def test_amcl_keeps_its_estimate_in_a_crowd(tmp_path: Path) -> None:
    """Eight people wandering the living room the robot crosses hide the walls amcl
    matches: their returns are left out of its scans (a laser filter on tracked people), so
    the estimate holds and the robot gets through; with them in, this run lost it (0.8 m)."""
    mission = tmp_path / "crowd.yaml"
    mission.write_text(
        "name: crowd\nworld: small_house\nstart: {x: -6.0, y: -2.0, yaw: 0.0}\nseed: 7\n"
        "people:\n  - {count: 8, area: livingroom, speed: 1.0}\n"
        "tasks:\n  - {type: go_to, pose: {x: 7.0, y: -2.0, yaw: 0.0}}\nlimits: {time: 150.0}\n"
    )
    record = run_mission(load_mission(mission))
    assert record.status == "succeeded", record.reason
    assert record.metrics["localization"]["position_rmse"] < 0.1
    people = record.metrics["people"]
    assert people["collisions"] == 0 and people["min_distance"] > 0.2
    assert people["time_not_moving"] < 0.1 * record.sim_time


def test_a_start_on_a_cell_edge_by_a_wall_escapes_as_the_planner_sees_it() -> None:
    """A round-number pose on a cell's edge stands on both cells; the planners refuse it
    when either is too near a wall, so the navigator must see it so too and step out
    (it saw only one cell: the robot spun, waited and failed 'start is not free')."""
    from agv_mission.geometry import Pose2D
    from agv_mission.navigation.reachability import escape_point
    from agv_mission.planners.free_space import FreeSpace

    navigator = sample_context().handle.navigator  # a real navigator in a 4 m room
    costmap = navigator.costmap
    margin = navigator.global_planner.clearance + 0.01
    grid = costmap.grid
    row = grid.height // 2
    centres = grid.cell_to_world(np.full(grid.width, row), np.arange(grid.width))
    free = costmap.is_free(centres, margin)
    col = int(np.flatnonzero(~free[:-1] & free[1:])[0])  # a wall's side: not free | free
    edge = grid.origin.x + (col + 1) * grid.resolution  # their shared edge
    pose = Pose2D(edge, float(centres[col, 1]), 0.0)
    space = FreeSpace(costmap, navigator.global_planner.clearance)
    assert not space.point_free(pose.x - grid.origin.x, pose.y - grid.origin.y)
    out = escape_point(costmap, pose, margin, navigator.config.escape_distance)
    assert out is not None and bool(costmap.is_free(np.array([out.x, out.y]), margin))


def test_a_route_through_a_door_of_0_8_m_is_walked_wherever_the_grid_falls() -> None:
    """Two rooms joined by a 0.8 m door (people of 0.25 m fit, with 0.15 m to spare), the
    door shifted across the routing grid's 0.25 m cells: always one piece of walkable space
    and a person walks through (cell centres alone lost such doors)."""
    from agv_mission.geometry import Pose2D
    from agv_mission.maps.grid import FREE, OCCUPIED, OccupancyGrid

    for shift in (0.0, 0.05, 0.10, 0.15, 0.20):
        data = np.full((80, 160), FREE, dtype=np.int8)  # 8 x 4 m at 5 cm
        data[[0, -1], :] = data[:, [0, -1]] = OCCUPIED
        data[:, 78:82] = OCCUPIED  # a 0.2 m wall at x = 3.9..4.1
        door = int(round((1.5 + shift) / 0.05))
        data[door : door + 16, 78:82] = FREE  # 0.8 m wide
        grid = OccupancyGrid(data, 0.05, Pose2D(0.0, 0.0, 0.0))
        route = ((1.0, 3.0), (7.0, 3.0))
        crowd = Crowd(
            [PeopleGroup(count=1, behaviour="route", route=route, speed=1.2)],
            grid,
            np.random.default_rng(0),
        )
        router = crowd._routers[0]
        west, east = (router.component(router.node(p)) for p in route)
        assert west == east >= 0, shift
        walk = _walk(crowd, 200)
        assert (walk[:, 0, 0] > 6.5).any(), shift  # through the door to the far side
        assert _wall_gap(grid, walk, crowd.radii) > -0.03
