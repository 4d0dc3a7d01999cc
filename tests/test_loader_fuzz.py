"""The loader under random input: it returns a LoadedMission or raises MissionError, never
anything else (an uncaught exception would be a traceback at the command line).

Three kinds of input: random documents built from the schema's own key names and values
(so many get past YAML and pydantic and reach world, robot, rooms and pose checks), the
same with random ``--set`` overrides, and random YAML-ish text.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.resolved import LoadedMission

HERE = Path(__file__).resolve().parent
MISSION = HERE / "invalid" / "fuzz.yaml"  # never written: its folder resolves data/ paths

SETTINGS = settings(
    max_examples=200,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)

KEYS = [
    # mission
    "name", "world", "rooms", "robot", "start", "seed", "stack", "simulation", "tasks",
    "limits", "recorder", "output",
    # tasks and poses
    "type", "pose", "x", "y", "z", "w", "yaw", "position", "orientation", "waypoints",
    "loops", "dwell", "duration", "min_range", "speed", "turn_rate", "sector", "room",
    "record",
    # stack
    "localization", "global_planner", "local_planner", "costmap", "navigation", "planner",
    "time_limit", "simplify", "clearance", "inflation_radius", "resolution", "horizon",
    "lookahead", "physics_dt", "time",
]  # fmt: skip
WORDS = [
    "go_to", "patrol", "wander", "visit_rooms", "record_room", "ompl", "grid_astar", "mpc",
    "pure_pursuit", "amcl", "ground_truth", "odometry", "turtlebot3_world", "small_house",
    "burger", "waffle", "rosbots", "RRTConnect", "RRTstar", "PRM", "center", "north",
    "kitchen", "livingroom", "bedroom", "data/arena.world.yaml", "data/bad.rooms.yaml",
    "data/bad.robot.yaml", "data/bad.recorder.yaml", "data/noimage.map.yaml", "nowhere",
    "", "~", "/", "..", "a\x00b", "~nosuchuser/x", "x" * 300,
]  # fmt: skip

numbers = st.one_of(
    st.integers(min_value=-5, max_value=5),
    st.integers(),
    st.floats(min_value=-4.0, max_value=4.0),
    st.floats(allow_nan=True, allow_infinity=True),
)
scalars = st.one_of(st.none(), st.booleans(), numbers, st.sampled_from(WORDS), st.text(max_size=12))
keys = st.integers(0, 9).flatmap(
    lambda i: (
        st.one_of(st.integers(-2, 2), st.booleans(), st.dates())
        if i == 0
        else st.one_of(st.sampled_from(KEYS), st.text(max_size=8))
    )
)
junk = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(keys, inner, max_size=5)),
    max_leaves=12,
)


# Near-valid missions: every part usually right, any part sometimes junk.
def maybe(strategy: st.SearchStrategy) -> st.SearchStrategy:
    return st.integers(0, 11).flatmap(lambda i: junk if i == 0 else strategy)


coord = st.one_of(
    st.floats(-1.9, 1.9), st.floats(-1.9, 1.9), st.floats(-4.0, 4.0), st.integers(-4, 4)
)
unit = st.floats(-1.0, 1.0)
flat_pose = st.fixed_dictionaries(
    {"x": maybe(coord), "y": maybe(coord)}, optional={"yaw": maybe(coord)}
)
ros_pose = st.fixed_dictionaries(
    {
        "position": maybe(st.fixed_dictionaries({"x": coord, "y": coord}, optional={"z": coord})),
    },
    optional={
        "orientation": maybe(
            st.fixed_dictionaries(
                {"z": maybe(unit), "w": maybe(unit)}, optional={"x": unit, "y": unit}
            )
        )
    },
)
pose = st.one_of(flat_pose, flat_pose, ros_pose)
room = st.sampled_from(["center", "north", "south", "east", "west", "kitchen", "nowhere"])
task = st.one_of(
    st.fixed_dictionaries({"type": st.just("go_to"), "pose": maybe(pose)}),
    st.fixed_dictionaries(
        {"type": st.just("patrol"), "waypoints": maybe(st.lists(pose, max_size=3))},
        optional={"loops": maybe(st.integers(-1, 3)), "dwell": maybe(numbers)},
    ),
    st.fixed_dictionaries(
        {"type": st.just("wander"), "duration": maybe(numbers)},
        optional={"min_range": maybe(numbers)},
    ),
    st.fixed_dictionaries(
        {"type": st.just("visit_rooms"), "rooms": maybe(st.lists(room, max_size=3))},
        optional={"record": maybe(st.booleans())},
    ),
    st.fixed_dictionaries({"type": st.just("record_room"), "room": maybe(room)}),
)
plugin = st.one_of(
    st.fixed_dictionaries(
        {"type": st.just("ompl")},
        optional={
            "planner": maybe(st.sampled_from(["RRTConnect", "RRTstar", "PRM", "Nope"])),
            "time_limit": maybe(numbers),
        },
    ),
    st.fixed_dictionaries({"type": st.sampled_from(["grid_astar", "mpc", "pure_pursuit"])}),
    st.fixed_dictionaries({"type": st.sampled_from(["amcl", "ground_truth", "odometry"])}),
    junk,
)
stack = st.fixed_dictionaries(
    {},
    optional={
        "localization": maybe(plugin),
        "global_planner": maybe(plugin),
        "local_planner": maybe(plugin),
        "costmap": maybe(st.fixed_dictionaries({}, optional={"inflation_radius": numbers})),
    },
)
mission = st.fixed_dictionaries(
    {"tasks": maybe(st.lists(maybe(task), min_size=1, max_size=3))},
    optional={
        "name": maybe(st.one_of(st.sampled_from(["m", "fuzz-1", "a b"]), st.text(max_size=6))),
        "world": maybe(st.sampled_from(["turtlebot3_world", "data/arena.world.yaml", "moon"])),
        "robot": maybe(st.sampled_from(["burger", "waffle", "data/bad.robot.yaml"])),
        "rooms": maybe(st.sampled_from(["data/bad.rooms.yaml", "data/nope.yaml"])),
        "start": maybe(st.one_of(pose, room)),
        "seed": maybe(st.integers(-2, 2**40)),
        "stack": maybe(stack),
        "limits": maybe(st.fixed_dictionaries({"time": numbers})),
        "recorder": maybe(st.sampled_from(["data/bad.recorder.yaml", "data/none.yaml"])),
        "output": maybe(st.sampled_from(["runs", "out/x"])),
    },
)
documents = st.one_of(
    mission, mission, mission, mission, st.dictionaries(keys, junk, max_size=6), junk
)

overrides = st.lists(
    st.builds(
        lambda path, value: f"{path}={value}",
        st.one_of(
            st.sampled_from(
                [
                    "tasks.0.loops",
                    "tasks.0.pose.x",
                    "seed",
                    "stack.global_planner.type",
                    "stack.local_planner.type",
                    "start",
                    "tasks.9",
                    "tasks.0.x.y",
                    "world",
                    ".",
                ]
            ),  # fmt: skip
            st.lists(st.one_of(st.sampled_from(KEYS), st.text(max_size=4)), max_size=4).map(
                ".".join
            ),
        ),
        st.one_of(st.sampled_from(WORDS), st.text(max_size=8), numbers.map(str)),
    ),
    max_size=3,
)

FRAGMENTS = [
    "tasks:", "- ", "  ", "\t", "type: go_to", "pose: {x: 0.5, y: -0.5}", "{", "}", "[",
    "]", ", ", ": ", "'", '"', "&a ", "*a", "!!str ", "!!python/name:os.system ", "? ",
    "---", "...", "#", "x: 1", "y: .nan", "- {type: wander, duration: 5}", "world: ",
    "start: ", "seed: -1", "%YAML 1.1", "\\ud800", "\x85", "\ufeff", "|", ">",
]  # fmt: skip
yamlish = st.lists(
    st.lists(st.one_of(st.sampled_from(FRAGMENTS), st.text(max_size=5)), max_size=6).map("".join),
    max_size=8,
).map("\n".join)


LATE = ("outside the map", "obstacle", "unknown space", "unknown room", "finite pose", "file")


def check(text: str, sets: list[str] | None = None) -> None:
    try:
        result = load_mission(MISSION, sets, text=text)
    except MissionError as exc:
        assert exc.problems and all(isinstance(p, Problem) for p in exc.problems)
        for p in exc.problems:
            assert p.file in (str(MISSION), "--set")
            assert p.line is None or p.line >= 1
            assert p.message and "Traceback" not in p.message and str(p)
        first = exc.problems[0]
        late = any(word in first.message for word in LATE)
        event("rejected after loading the world" if late else "rejected before")
        return
    event("loaded")
    assert isinstance(result, LoadedMission)
    for v in (result.start.x, result.start.y, result.start.yaw):
        assert math.isfinite(v)
    result.resolved()


def dump(doc: Any) -> str:
    return yaml.safe_dump(doc, allow_unicode=True, sort_keys=False)


@SETTINGS
@given(documents)
def test_random_documents_never_crash_the_loader(doc: Any) -> None:
    check(dump(doc))


@settings(SETTINGS, max_examples=100)
@given(mission, overrides)
def test_random_overrides_never_crash_the_loader(doc: Any, sets: list[str]) -> None:
    check(dump(doc), sets)


@settings(SETTINGS, max_examples=150)
@given(st.one_of(yamlish, st.text(max_size=200)))
def test_random_text_never_crashes_the_loader(text: str) -> None:
    check(text)


def test_hostile_documents() -> None:
    """Cases found while fuzzing, kept as plain examples."""
    for text in (
        "a: &x [*x]\n",  # an alias that contains itself
        "tasks: &t [*t]\n",
        "a: " + "[" * 600 + "]" * 600 + "\n",  # deeper than Python's recursion limit
        "seed: 1\nseed: 2\ntasks: [{type: wander, duration: 1}]\n",  # duplicate key
        'name: "\\ud800"\ntasks: [{type: wander, duration: 1}]\n',  # lone surrogate
        "tasks: [{type: go_to, pose: {x: 0.5, y: -0.5, yaw: .nan}}]\n",
        "world: ~nosuchuser/w\ntasks: [{type: wander, duration: 1}]\n",
        "robot: " + "r" * 5000 + "\ntasks: [{type: wander, duration: 1}]\n",
        "world: " + "w" * 5000 + "\ntasks: [{type: wander, duration: 1}]\n",
        'robot: "a\\0b"\nrecorder: "a\\0b"\ntasks: [{type: wander, duration: 1}]\n',
        "robot: data/scalar.robot.yaml\ntasks: [{type: wander, duration: 1}]\n",
        "? [a, b]\n: 1\n",
        "seed: 1\x07\n",
    ):
        try:
            load_mission(MISSION, text=text)
        except MissionError:
            continue
        raise AssertionError(f"accepted: {text[:60]!r}")
