"""The JSON Schema accepts exactly what the tool accepts (up to checks it cannot express)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import jsonschema
import pytest
import yaml

from agv_mission.missions.load import schema as mission_schema
from agv_mission.missions.load.schema import FIELD_ORDER
from agv_mission.robots.builtin_robots import BUILTIN_ROBOTS
from agv_mission.robots.robot_files import robot_json_schema
from cli_in_process import agv

REPO = Path(__file__).resolve().parents[1]
MISSIONS = sorted(
    [
        *(REPO / "missions").glob("*.yaml"),
        *(REPO / "tests" / "scenarios").rglob("*.yaml"),
        *(REPO / "src" / "agv_mission" / "data" / "missions").glob("*.yaml"),
    ]
)
INVALID = sorted((REPO / "tests" / "invalid").glob("*.yaml"))

# Invalid files the schema cannot tell from valid ones, by the kind of check they need.
BEYOND_THE_SCHEMA = {
    # the world's geometry and files: where obstacles, unknown space and the map are
    "pose_in_unknown_space": "geometry",
    "pose_in_unknown_space_builtin": "geometry",
    "pose_inside_custom_pillar": "geometry",
    "pose_inside_pillar": "geometry",
    "pose_inside_wall": "geometry",
    "pose_outside_map": "geometry",
    "start_inside_obstacle": "geometry",
    "start_outside_map": "geometry",
    "start_unknown_room": "rooms of the world",
    "visit_unknown_room": "rooms of the world",
    "unknown_robot": "built-in robots and robot files",
    "unknown_world": "built-in worlds and world files",
    "dock_unknown_name": "docks of the world",
    "fleet_kidnap_unnamed": "whether the mission is a fleet",
    "fault_unknown_robot": "the names in robots:",
    "fault_robot_without_fleet": "whether the mission is a fleet",
    "world_file_too_fine": "another file",
    "unknown_planner_name": "the planners the installed OMPL has",
    "costmap_resolution_too_fine": "cells of the world's map",
    # files named by the mission
    "malformed_recorder_file": "another file",
    "malformed_robot_file": "another file",
    "malformed_rooms_file": "another file",
    "malformed_world_file": "another file",
    "missing_recorder_file": "another file",
    "missing_robot_file": "another file",
    "missing_rooms_file": "another file",
    "missing_world_file": "another file",
    "ros_map_missing_image": "another file",
    "robot_file_not_a_mapping": "another file",
    "robot_lidar_beams_too_many": "another file",
    "robot_non_finite": "another file",
    "world_is_a_directory": "another file",
    "world_is_dev_zero": "another file",
    "rooms_is_a_directory": "another file",
    "robot_battery_negative_capacity": "another file",
    "robot_integer_too_long": "another file",
    "robot_wheel_too_small": "another file",
    "robot_lidar_range_inverted": "another file",
    "ros_map_image_bomb": "another file",
    "ros_map_image_too_large": "another file",
    "world_file_too_large": "another file",
    "sdf_world_too_large": "another file",
    "recorder_integer_too_long": "another file",
    "robot_footprint_radius_too_large": "another file",
    "rooms_dock_outside_map": "another file",
    "world_dock_in_wall": "another file",
    "rooms_anchor_outside": "another file",
    "rooms_bowtie": "another file",
    "rooms_duplicate_label": "another file",
    "goal_within_planner_clearance": "geometry",
    "map_area_bounds_outside_map": "geometry",
    "map_area_bounds_too_large": "cells of a SLAM map",
    # arithmetic on values: quaternion length, non-finite numbers (JSON has none), order
    "quaternion_not_unit": "arithmetic",
    "quaternion_tilted": "arithmetic",
    "quaternion_zero": "arithmetic",
    "pose_non_finite_yaw": "non-finite number",
    "plugin_option_nan": "non-finite number",
    # YAML itself: duplicate keys and lone surrogates are gone once parsed
    "yaml_duplicate_key": "YAML",
    "yaml_duplicate_nested_key": "YAML",
    "yaml_lone_surrogate": "YAML",
    "yaml_alias_bomb": "YAML",  # the aliases' expansion, counted before it is built
}


@functools.cache
def _mission_validator() -> jsonschema.Draft202012Validator:
    """One validator for the whole module: generating the schema takes a tenth of a second."""
    return jsonschema.Draft202012Validator(mission_schema.mission_json_schema())


def mission_json_schema() -> dict:
    return _mission_validator().schema


def _parsed(path: Path) -> object:
    return yaml.safe_load(path.read_text(encoding="utf-8"))


@pytest.mark.parametrize("path", MISSIONS, ids=[p.stem for p in MISSIONS])
def test_every_shipped_mission_validates_against_the_schema(path: Path) -> None:
    _mission_validator().validate(_parsed(path))


def _schema_accepts(path: Path) -> bool:
    try:
        doc = _parsed(path)
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError, ValueError):
        return False  # not even YAML (or a number Python will not read): the schema never sees it
    try:
        return _mission_validator().is_valid(doc)
    except RecursionError:
        return False


def test_every_invalid_file_fails_the_schema_unless_listed() -> None:
    accepted = {p.stem for p in INVALID if _schema_accepts(p)}
    unexplained = accepted - set(BEYOND_THE_SCHEMA)
    assert not unexplained, f"the schema accepts these invalid files: {sorted(unexplained)}"
    stale = {s for s in BEYOND_THE_SCHEMA if (REPO / "tests" / "invalid" / f"{s}.yaml").exists()}
    assert stale - accepted == set(), f"listed but rejected by the schema: {stale - accepted}"


def test_the_schema_declares_its_dialect_and_is_itself_valid() -> None:
    for schema in (mission_json_schema(), robot_json_schema()):
        assert schema["$schema"] == "https://json-schema.org/draft/2020-12/schema"
        jsonschema.Draft202012Validator.check_schema(schema)


def test_mission_yaml_writes_every_key_of_the_schema() -> None:
    """``mission.yaml`` (the resolved mission) keeps only the keys of ``FIELD_ORDER``: a key
    the schema gains must be added there, or runs would silently drop it."""
    assert sorted(mission_json_schema()["properties"]) == sorted(FIELD_ORDER)


def test_ros_style_poses_and_their_mistakes() -> None:
    schema = mission_json_schema()
    ros = {
        "position": {"x": 0.13, "y": 1.93, "z": 0.0},
        "orientation": {"x": 0.0, "y": 0.0, "z": -0.64003024, "w": -0.76812292098},
    }
    ok = {"tasks": [{"type": "go_to", "pose": ros}]}
    jsonschema.validate(ok, schema)
    for bad_pose in (
        {**ros, "yaw": 1.0},  # mixes the spellings
        {"position": {"x": 1.0}},  # no y
        {"orientation": {"z": 0.0, "w": 1.0, "roll": 0.0}},
        {},
    ):
        assert not jsonschema.Draft202012Validator(schema).is_valid(
            {"tasks": [{"type": "go_to", "pose": bad_pose}]}
        ), bad_pose


def test_booleans_and_strings_are_not_numbers_to_either() -> None:
    schema = mission_json_schema()
    for doc in (
        {"seed": True, "tasks": [{"type": "wander", "duration": 5}]},
        {"tasks": [{"type": "wander", "duration": "5"}]},
        {"tasks": [{"type": "patrol", "waypoints": [{"x": 0, "y": 0}], "loops": True}]},
    ):
        assert not jsonschema.Draft202012Validator(schema).is_valid(doc), doc


def test_builtin_robots_validate_against_the_robot_schema() -> None:
    schema = robot_json_schema()
    for robot in BUILTIN_ROBOTS.values():
        doc = robot.model_dump(mode="json")
        doc.pop("name")  # optional in a file
        jsonschema.validate(doc, schema)
    assert not jsonschema.Draft202012Validator(schema).is_valid(
        {**BUILTIN_ROBOTS["burger"].model_dump(mode="json"), "lidar": {"beams": 10**9}}
    )


def test_schema_command_prints_both_schemas() -> None:
    for args, title in ((["schema"], "Mission"), (["schema", "--robot"], "RobotDescription")):
        r = agv(*args)  # in this process: test_cli.py starts the program for ``schema``
        assert r.returncode == 0, r.stderr
        assert json.loads(r.stdout)["title"] == title
