"""Keepout and speed-limit zones (people-and-zones.md): validation, Nav2 masks, every
planner kept out, the speed cap, metrics.zones, the bag's filter masks and the CLI's exit
code. The scenarios of tests/scenarios (keepout room, speed zone by a door, started inside
a keepout zone) run in test_regress."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from shapely import Point, Polygon
from typer.testing import CliRunner

from agv_mission.bags.writer import BagWriter
from agv_mission.cli import app
from agv_mission.geometry import Pose2D
from agv_mission.maps.costmap import LETHAL
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import make_run_dir, write_run
from agv_mission.missions.run.runner import run_mission
from agv_mission.registry import registry

HOUSE = """\
name: zones
world: small_house
start: {{x: 6.5, y: -4.0, yaw: 1.5708}}
seed: 2
stack:
  localization: {{type: ground_truth}}
zones:
{zones}
tasks:
  - {{type: go_to, pose: {{x: 2.0, y: 1.0, yaw: 0.0}}}}
limits: {{time: 60.0}}
"""


def write(tmp_path: Path, zones: str, name: str = "m.yaml") -> Path:
    path = tmp_path / name
    path.write_text(HOUSE.format(zones=zones))
    return path


def problems(path: Path) -> list[tuple[int | None, str, str]]:
    with pytest.raises(MissionError) as exc:
        load_mission(path)
    return [(p.line, p.field, p.message) for p in exc.value.problems]


def test_zone_problems_name_line_and_field(tmp_path: Path) -> None:
    found = problems(
        write(
            tmp_path,
            "  - {type: keepout, room: kitchen, polygon: [[0, 0], [1, 0], [1, 1]]}\n"
            "  - {type: keepout, polygon: [[0, 0], [1, 1], [1, 0], [0, 1]]}\n"
            "  - {type: speed_limit, polygon: [[0, 0], [1, 0], [1, 1]]}\n"
            "  - {type: speed_limit, room: kitchen, percent: 150}\n"
            "  - {type: keepout, polygon: [[0, 0, 1], [1, 0], [1, 1]]}\n",
        )
    )
    lines = {line for line, _, _ in found}
    assert lines == {8, 9, 10, 11, 12}, found
    text = "\n".join(f"{line} {field} {msg}" for line, field, msg in found)
    assert "not both" in text and "must be simple" in text and "max_speed" in text
    assert any(field == "zones.3.percent" for _, field, _ in found), found
    assert any(field.startswith("zones.4.polygon.0") for _, field, _ in found), found


def test_unknown_room_and_missing_mask(tmp_path: Path) -> None:
    found = problems(
        write(
            tmp_path,
            "  - {type: keepout, room: garage}\n  - {type: speed_mask, map: nowhere.yaml}\n",
        )
    )
    assert [(line, field) for line, field, _ in found] == [(8, "zones.0.room"), (9, "zones.1.map")]
    assert "no room 'garage'" in found[0][2] and "kitchen" in found[0][2]
    assert "nowhere.yaml" in found[1][2]
    result = CliRunner().invoke(app, ["validate", str(tmp_path / "m.yaml")])
    assert result.exit_code == 2, result.output
    assert "m.yaml:8" in result.output and "Traceback" not in result.output


def mask(tmp_path: Path, name: str, values: np.ndarray) -> Path:
    """A map_server mask over the house's livingroom corner, in ``raw`` mode (each cell is
    its pixel's value), as Nav2's filter tutorials write speed masks."""
    pixels = values.astype(np.uint8)
    Image.fromarray(pixels[::-1]).save(tmp_path / f"{name}.png")
    (tmp_path / f"{name}.yaml").write_text(
        f"image: {name}.png\nresolution: 0.1\norigin: [0.0, -5.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: raw\n"
    )
    return tmp_path / f"{name}.yaml"


def test_nav2_masks_keepout_and_speed(tmp_path: Path) -> None:
    values = np.zeros((20, 20))  # 2 m x 2 m from (0, -5)
    values[:10, :10] = 100.0  # keepout: (0..1, -5..-4)
    mask(tmp_path, "keepout", values)
    speed = np.zeros((20, 20))
    speed[10:, 10:] = 40.0  # base 100 + multiplier -1 * 40 = 60 % of the maximum
    mask(tmp_path, "speed", speed)
    path = write(
        tmp_path,
        "  - {type: keepout_mask, map: keepout.yaml}\n"
        "  - {type: speed_mask, map: speed.yaml, base: 100.0, multiplier: -1.0, unit: percent}\n",
    )
    loaded = load_mission(path)
    zones = loaded.zones
    assert zones is not None
    assert zones.keepout_clearance(0.5, -4.5) == 0.0
    assert zones.keepout_clearance(1.5, -3.5) > 0.5
    assert loaded.costmap.cost_at(np.array([[0.5, -4.5]]))[0] == LETHAL
    top = loaded.robot.max_linear_velocity
    assert zones.limit_at(1.5, -3.5) == pytest.approx(0.6 * top)
    assert zones.limit_at(0.5, -3.5) == float("inf")  # 0 in a speed mask: no limit (Nav2)
    # Approaching at full speed the cap brakes ahead: sqrt(L^2 + 2 a d) rises with d.
    caps = [zones.speed_cap(2.0 + d, -3.5, 1.0, 0.0) for d in (0.0, 0.2, 0.6)]
    assert caps[0] < caps[1] < caps[2]


@pytest.mark.parametrize(
    "planner",
    [{"type": "cost_grid"}, {"type": "grid_astar"}, {"type": "ompl", "planner": "RRTConnect"}],
)
def test_every_planner_keeps_out(tmp_path: Path, planner: dict) -> None:
    """The keepout room the shortest way crosses is lethal for every global planner."""
    path = write(tmp_path, "  - {type: keepout, room: livingroom}\n")
    text = path.read_text().replace(
        "stack:\n", f"stack:\n  global_planner: {json.dumps(planner)}\n"
    )
    loaded = load_mission(path, text=text)
    config = loaded.mission.stack.global_planner
    assert config.type == planner["type"]
    plan = registry.create("global_planner", config).plan(
        loaded.costmap, loaded.start, Pose2D(2.0, 1.0, 0.0), seed=1
    )
    room = Polygon(loaded.rooms["livingroom"].polygon)
    radius = loaded.robot.footprint_radius
    dense = np.concatenate(
        [
            np.linspace(a, b, 10)
            for a, b in zip(plan.points[:-1, :2], plan.points[1:, :2], strict=True)
        ]
    )
    assert min(room.distance(Point(*p)) for p in dense) >= radius


def test_speed_zone_run_metrics_and_bag(tmp_path: Path) -> None:
    path = tmp_path / "speed.yaml"
    path.write_text(
        "name: speed\nworld: small_house\nstart: {x: 2.0, y: -2.0, yaw: 0.0}\nseed: 1\n"
        "stack: {localization: {type: ground_truth}}\n"
        "zones:\n"
        "  - {type: speed_limit, polygon: [[3.0, -3.0], [4.4, -3.0], [4.4, -1.0], [3.0, -1.0]],"
        " max_speed: 0.08}\n"
        "  - {type: keepout, polygon: [[0.5, -5.3], [2.0, -5.3], [2.0, -3.2], [0.5, -3.2]]}\n"
        "tasks:\n  - {type: go_to, pose: {x: 4.0, y: -2.0, yaw: 0.0}}\nlimits: {time: 40.0}\n"
    )
    loaded = load_mission(path)
    run_dir = make_run_dir(tmp_path / "runs", loaded.name)
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    write_run(run_dir, loaded, record)
    assert record.status == "succeeded", record.reason
    zones = json.loads((run_dir / "result.json").read_text())["metrics"]["zones"]
    assert zones["keepout_time"] == 0.0 and not zones["started_in_keepout"]
    assert zones["speed_limited_time"] > 3.0
    assert zones["speed_violation_time"] == 0.0 and 0.8 < zones["max_speed_ratio"] <= 1.05
    # the command inside the zone: no more than the limit
    traj = record.trajectory
    inside = np.array([loaded.zones.limit_at(x, y) < 1.0 for x, y in traj[:, 1:3]])
    assert np.abs(traj[inside, 7]).max() <= 0.08 + 1e-6
    store = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(run_dir / "bag") as reader:
        conns = [c for c in reader.connections if c.topic.endswith("_filter_mask")]
        assert sorted(c.topic for c in conns) == ["/keepout_filter_mask", "/speed_filter_mask"]
        assert all("TRANSIENT_LOCAL" in str(c.ext.offered_qos_profiles) for c in conns)
        got = {}
        for conn, t, raw in reader.messages(connections=conns):
            grid = store.deserialize_cdr(raw, conn.msgtype)
            got[conn.topic] = (t, set(np.unique(np.asarray(grid.data)).tolist()))
    assert got["/keepout_filter_mask"] == (0, {0, 100})
    assert got["/speed_filter_mask"][0] == 0 and got["/speed_filter_mask"][1] == {0, 37}
    assert (run_dir / "run.png").stat().st_size > 0


def test_dashboard_zones_message(tmp_path: Path) -> None:
    """The live stream's ``zones`` message: keepout red, speed blue, on the map's grid."""
    import base64
    import io

    from agv_mission.service.stream_messages import zones_message

    loaded = load_mission(
        write(
            tmp_path,
            "  - {type: keepout, polygon: [[0.5, -5.3], [2.0, -5.3], [2.0, -3.2], [0.5, -3.2]]}\n"
            "  - {type: speed_limit, room: kitchen, percent: 50}\n",
        )
    )
    zones = loaded.zones
    message = zones_message(zones.keepout_grid(), zones.speed_grid())
    assert message["type"] == "zones" and message["width"] == zones.grid.width
    image = np.asarray(Image.open(io.BytesIO(base64.b64decode(message["png"]))))
    grid = zones.grid

    def pixel(x: float, y: float) -> np.ndarray:
        row, col = grid.world_to_cell(np.array([x, y]))
        return image[grid.height - 1 - int(row), int(col)]  # row 0 at the top

    assert tuple(pixel(1.0, -4.0)[:3]) == (217, 70, 60) and pixel(1.0, -4.0)[3] > 0
    assert tuple(pixel(7.0, -2.0)[:3]) == (40, 90, 255) and pixel(7.0, -2.0)[3] > 0
    assert pixel(-5.0, -2.0)[3] == 0  # the bedroom: no zone


def test_masks_travel_with_a_mission_to_the_service(tmp_path: Path) -> None:
    """``submit`` sends the files a mission names: a mask's YAML and its image too."""
    from agv_mission.service.client import mission_files

    mask(tmp_path, "keepout", np.full((20, 20), 100.0))
    path = write(tmp_path, "  - {type: keepout_mask, map: keepout.yaml}\n")
    names = {p.name for p in mission_files(path, path.read_text(), [], None)}
    assert {"keepout.yaml", "keepout.png"} <= names


def test_a_goal_in_a_keepout_zone_fails_with_the_reason(tmp_path: Path) -> None:
    path = write(tmp_path, "  - {type: keepout, room: recreationroom}\n")
    record = run_mission(load_mission(path, ["limits.time=60"]))
    assert record.status == "failed"
    assert "(2.00, 1.00) lies in a keepout zone" in record.reason


def test_from_the_middle_of_a_keepout_zone_the_way_out_nearest_the_goal(tmp_path: Path) -> None:
    """Every side of a square zone is as near from its middle: the robot leaves by the one
    towards its goal (ties broken by the goal), wherever the goal is."""
    square = "  - {type: keepout, polygon: [[5.5, -5.0], [7.5, -5.0], [7.5, -3.0], [5.5, -3.0]]}\n"
    zones = load_mission(write(tmp_path, square)).zones
    assert zones is not None
    margin = 0.1
    for goal, side in (((9.0, -4.0), "east"), ((3.0, -4.0), "west"), ((6.5, 0.0), "north")):
        x, y = zones.exit_point(6.5, -4.0, margin, goal)
        assert {"east": x > 7.5, "west": x < 5.5, "north": y > -3.0}[side], (goal, x, y)
        assert zones.keepout_clearance(x, y) > zones.robot_radius + margin
