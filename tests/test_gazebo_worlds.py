"""Gazebo worlds read directly (robots-and-worlds.md): bodies, poses, the state, refusals at
their lines, hostile XML, and the world's map."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from agv_mission.maps.grid import OCCUPIED
from agv_mission.maps.ros_map import load_ros_map
from agv_mission.maps.world_loader import WorldError, load_world
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from cli_in_process import agv as agv_here

BARN = Path(__file__).parent / "data" / "barn"


def sdf(body: str, version: str = "1.6") -> str:
    return f'<?xml version="1.0"?>\n<sdf version="{version}">\n<world name="default">\n{body}</world>\n</sdf>\n'


def model(
    name: str, geometry: str, pose: str = "0 0 0 0 0 0", static: str = "1", link: str = ""
) -> str:
    return (
        f'<model name="{name}"><static>{static}</static><pose>{pose}</pose>\n'
        f'<link name="link">{link}<collision name="c"><geometry>{geometry}</geometry>'
        "</collision></link></model>\n"
    )


def cylinder(radius: float = 0.1, length: float = 1.0) -> str:
    return f"<cylinder><radius>{radius}</radius><length>{length}</length></cylinder>"


def write(tmp_path: Path, text: str, name: str = "w.world") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_a_barn_world_is_its_state_poses_cylinders(tmp_path):
    path = BARN / "world_0.world"
    world = load_world(str(path), scan_height=0.3)
    text = path.read_text()
    state = text[text.index("<state") :]
    placed = {
        name: tuple(float(v) for v in pose.split()[:2])
        for name, pose in re.findall(r"<model name='(\w+)'>\s*<pose frame=''>([^<]*)</pose>", state)
        if name != "ground_plane"
    }
    assert len(world.cylinders) == len(placed) == 209
    assert not world.boxes
    got = sorted((round(c.x, 6), round(c.y, 6)) for c in world.cylinders)
    assert got == sorted(placed.values())
    assert {c.radius for c in world.cylinders} == {0.075}
    assert world.imported == {}


def test_the_state_pose_wins_over_the_models_own(tmp_path):
    state = (
        '<state world_name="default"><model name="a"><pose>2 3 0 0 0 0</pose>'
        '<link name="link"><pose>2 3 0 0 0 0</pose></link></model></state>\n'
    )
    world = load_world(str(write(tmp_path, sdf(model("a", cylinder()) + state))))
    (c,) = world.cylinders
    assert (c.x, c.y) == (2.0, 3.0)


def test_poses_compose_model_link_collision(tmp_path):
    geometry = "<box><size>1.0 0.4 2.0</size></box>"
    body = (
        '<model name="crate"><static>true</static><pose>1 2 0 0 0 1.5707963267948966</pose>'
        '<link name="l"><pose>1 0 0 0 0 0</pose><collision name="c">'
        f"<pose>0 0.5 0.5 0 0 0</pose><geometry>{geometry}</geometry></collision></link></model>"
    )
    world = load_world(str(write(tmp_path, sdf(body))))
    (b,) = world.boxes
    # the link 1 m along the model's x (world +y), the collision 0.5 m along its y (world -x)
    assert b.x == pytest.approx(0.5) and b.y == pytest.approx(3.0)
    assert (b.half_x, b.half_y) == pytest.approx((0.5, 0.2))
    assert b.yaw == pytest.approx(math.pi / 2)


def test_a_box_on_its_side_keeps_its_upright_axis(tmp_path):
    # rolled 90 degrees about x: its y axis is vertical, its footprint 1.0 x 2.0
    body = model(
        "slab", "<box><size>1.0 0.4 2.0</size></box>", pose="0 0 0.2 1.5707963267948966 0 0"
    )
    (b,) = load_world(str(write(tmp_path, sdf(body)))).boxes
    assert sorted((b.half_x, b.half_y)) == pytest.approx([0.5, 1.0])


def test_spheres_are_the_disc_the_scan_plane_cuts(tmp_path):
    body = model("ball", "<sphere><radius>0.5</radius></sphere>", pose="1 1 0.4 0 0 0")
    body += model("lamp", "<sphere><radius>0.2</radius></sphere>", pose="3 3 2.0 0 0 0")
    world = load_world(str(write(tmp_path, sdf(body))), scan_height=0.1)
    (c,) = world.cylinders
    assert c.radius == pytest.approx(math.sqrt(0.5**2 - 0.3**2))
    (above,) = world.imported["not_cut"]
    assert above["item"].startswith("model 'lamp'") and above["z"] == [1.8, 2.2]


def test_a_mesh_is_refused_naming_the_file_the_line_and_the_mesh(tmp_path):
    mesh = "<mesh><uri>model://shelf/meshes/shelf.dae</uri></mesh>"
    text = sdf(model("pillar", cylinder()) + model("shelf", mesh, pose="2 0 0 0 0 0"))
    path = write(tmp_path, text)
    line = text.splitlines().index(next(t for t in text.splitlines() if "<mesh>" in t)) + 1
    with pytest.raises(WorldError) as err:
        load_world(str(path))
    (problem,) = err.value.problems
    assert problem.startswith(f"{path}:{line}: <mesh>: model 'shelf'")
    assert "shelf.dae" in problem
    done = agv_here("world", str(path), cwd=tmp_path)
    assert done.returncode == 2
    assert f"{path}:{line}: <mesh>" in done.stderr and "Traceback" not in done.stderr


def test_what_cannot_be_read_is_refused_each_at_its_line(tmp_path):
    lines = [
        model("log", cylinder(), pose="0 0 0.2 1.5707963267948966 0 0"),  # tilted
        model("cart", cylinder(), static="0"),
        "<include><uri>model://table</uri><pose>5 5 0 0 0 0</pose></include>\n",
        model("hill", "<heightmap><uri>file://h.png</uri></heightmap>"),
    ]
    text = sdf("".join(lines))
    path = write(tmp_path, text)
    with pytest.raises(WorldError) as err:
        load_world(str(path))
    problems = err.value.problems
    assert len(problems) == 4
    found = {re.match(rf"{re.escape(str(path))}:(\d+): <(\w+)>", p).groups() for p in problems}
    rows = text.splitlines()
    assert found == {
        (str(rows.index(lines[0].splitlines()[1]) + 1), "cylinder"),
        (str(rows.index(lines[1].splitlines()[0]) + 1), "static"),
        (str(rows.index(lines[2].strip()) + 1), "uri"),
        (str(rows.index(lines[3].splitlines()[1]) + 1), "heightmap"),
    }
    assert any("tilted cylinder" in p for p in problems)
    assert any("not a static model" in p for p in problems)
    assert any("model://table" in p and "does not hold" in p for p in problems)


def test_an_include_of_a_model_in_the_file_and_the_ground_plane_are_read(tmp_path):
    body = (
        "<include><uri>model://ground_plane</uri></include><include><uri>model://sun</uri></include>\n"
        + model("post", cylinder(0.2))
        + "<include><uri>model://post</uri><name>post2</name><pose>4 0 0 0 0 0</pose></include>\n"
    )
    world = load_world(str(write(tmp_path, sdf(body, "1.7"))))
    assert sorted((c.x, c.y) for c in world.cylinders) == [(0.0, 0.0), (4.0, 0.0)]


def test_skip_unsupported_runs_the_rest_and_lists_the_skipped(tmp_path):
    mesh = "<mesh><uri>model://x.dae</uri></mesh>"
    write(tmp_path, sdf(model("post", cylinder(0.2), pose="1 0 0 0 0 0") + model("m", mesh)))
    mission = {
        "world": "w.world",
        "world_import": {"skip_unsupported": True},
        "robot": "burger",
        "start": {"x": -1.0, "y": 0.0, "yaw": 0.0},
        "tasks": [{"type": "go_to", "pose": {"x": -0.7, "y": 0.0, "yaw": 0.0}}],
    }
    (tmp_path / "m.yaml").write_text(yaml.safe_dump(mission))
    with pytest.raises(MissionError) as err:
        load_mission(tmp_path / "m.yaml", ["world_import.skip_unsupported=false"])
    assert "<mesh>" in str(err.value.problems[0])
    loaded = load_mission(tmp_path / "m.yaml")
    (skipped,) = loaded.world.imported["skipped"]
    assert skipped["element"] == "mesh"
    assert (
        skipped["line"]
        == (tmp_path / "w.world")
        .read_text()
        .splitlines()
        .index(next(t for t in (tmp_path / "w.world").read_text().splitlines() if "<mesh>" in t))
        + 1
    )
    assert len(loaded.world.cylinders) == 1
    done = agv_here("run", "m.yaml", "--no-bag", "--output", "runs", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    (result,) = (tmp_path / "runs").glob("*/result.json")
    doc = yaml.safe_load(result.read_text())
    assert doc["world_import"]["skipped"][0]["reason"].startswith("a mesh")


BOMB = """<?xml version="1.0"?>
<!DOCTYPE sdf [
 <!ENTITY a "aaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaaa">
 <!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;&a;">
 <!ENTITY c "&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;&b;">
 <!ENTITY d "&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;&c;">
]>
<sdf version="1.6"><world name="w"><model name="&d;"><static>1</static></model></world></sdf>
"""


def test_entity_expansion_is_refused_without_expanding(tmp_path):
    path = write(tmp_path, BOMB)
    with pytest.raises(WorldError) as err:
        load_world(str(path))
    (problem,) = err.value.problems
    assert problem.startswith(f"{path}:3: <!ENTITY>: the entity 'a' refused without expanding")
    done = agv_here("world", str(path), cwd=tmp_path)
    assert done.returncode == 2 and "refused without expanding" in done.stderr


def test_an_external_entity_is_refused(tmp_path):
    text = (
        '<?xml version="1.0"?>\n<!DOCTYPE sdf [<!ENTITY x SYSTEM "file:///etc/passwd">]>\n'
        '<sdf version="1.6"><world name="w"><model name="&x;"/></world></sdf>\n'
    )
    with pytest.raises(WorldError) as err:
        load_world(str(write(tmp_path, text)))
    assert ":2: <!ENTITY>" in err.value.problems[0]
    assert "root:" not in str(err.value)


@pytest.mark.parametrize(
    ("text", "expect"),
    [
        ('<sdf version="2.0"><world name="w"/></sdf>', ":1: <sdf>: version '2.0' is not read"),
        (
            '<sdf version="1.6">\n<world name="w">\n<model name="a">\n</world></sdf>',
            ":4: not well-formed",
        ),
        ("<robot name='r'/>", ":1: <robot>: not a Gazebo world"),
        (sdf(model("a", "<box><size>1 -1 1</size></box>")), "<size> must be positive"),
        (sdf(model("a", cylinder(), pose="1 2 3")), "<pose>: expected 6 numbers"),
    ],
)
def test_malformed_worlds_name_their_line(tmp_path, text, expect):
    with pytest.raises(WorldError) as err:
        load_world(str(write(tmp_path, text)))
    assert expect in err.value.problems[0]


def test_save_map_is_the_cut_at_the_scan_height_with_2_m_around(tmp_path):
    body = model("post", cylinder(0.3), pose="1 1 0 0 0 0")
    body += model("high", "<box><size>1 1 0.2</size></box>", pose="-1 -1 1.0 0 0 0")  # above
    path = write(tmp_path, sdf(body))
    done = agv_here("world", str(path), "--save-map", str(tmp_path / "w_map"), cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    grid = load_ros_map(tmp_path / "w_map.yaml")
    assert grid.resolution == pytest.approx(0.05)
    assert grid.extent == pytest.approx((0.7 - 2.0, 1.3 + 2.0, 0.7 - 2.0, 1.3 + 2.0))
    rows, cols = grid.world_to_cell(np.array([[1.0, 1.0], [1.28, 1.0], [1.4, 1.0], [-1.0, -1.0]]))
    assert [int(v) for v in grid.data[rows, cols]] == [OCCUPIED, OCCUPIED, 0, 0]
    assert int((grid.data == OCCUPIED).sum()) == pytest.approx(math.pi * 0.3**2 / 0.05**2, rel=0.2)


BOX = "<box><size>{}</size></box>"


@pytest.mark.parametrize(
    ("body", "expect"),
    [
        # a body 1000 km long, a cylinder 200 km wide, two posts 2000 km apart: the map
        # would be terabytes (a MemoryError traceback before); refused at their lines
        (model("long", BOX.format("1e6 1 1"), pose="0 0 0.5 0 0 0"), [":5: <size>: model 'long'"]),
        (model("wide", cylinder(1e5), pose="0 0 0.5 0 0 0"), [":5: <cylinder>: model 'wide'"]),
        (
            model("east", BOX.format("1 1 1"), pose="1e6 0 0.5 0 0 0")
            + model("west", BOX.format("1 1 1"), pose="-1e6 0 0.5 0 0 0"),
            [":5: <size>: model 'east'", ":7: <size>: model 'west'"],
        ),
    ],
)
def test_a_world_too_large_to_rasterise_names_the_bodies_that_stretch_it(tmp_path, body, expect):
    path = write(tmp_path, sdf(body))
    done = agv_here("world", str(path), "--save-map", str(tmp_path / "m"), cwd=tmp_path)
    flat = " ".join(done.stdout.split() + done.stderr.split())
    assert done.returncode == 2, done.stdout + done.stderr
    assert "the world's map is too large" in flat and "at most 1e+08" in flat
    for where in expect:
        assert f"{path}{where}" in flat, flat
    assert not (tmp_path / "m.pgm").exists()


@pytest.mark.parametrize("where", ["model", "state"])
def test_a_pose_1e300_m_away_is_refused_at_its_line(tmp_path, where):
    """Not "empty bounds (1e+300, 1e+300, ...)" without a line (the box vanished in the
    rounding of its own bounds)."""
    far = "1e300 0 0.5 0 0 0"
    body = model("a", BOX.format("1 1 1"), pose=far if where == "model" else "0 0 0.5 0 0 0")
    if where == "state":
        body += (
            f'<state world_name="default">\n<model name="a"><pose>{far}</pose></model></state>\n'
        )
    with pytest.raises(WorldError) as err:
        load_world(str(write(tmp_path, sdf(body))))
    line = 4 if where == "model" else 7
    assert f":{line}: <pose>: model 'a': <pose>: x 1e+300 m is farther" in err.value.problems[0]


@pytest.mark.parametrize(("x", "half"), [(2e6, 1e6), (1e308, 1.7e308)])  # 1e308: inf bounds
def test_a_world_file_too_large_to_rasterise_is_invalid_input(tmp_path, x, half):
    path = write(
        tmp_path,
        yaml.safe_dump(
            {
                "spawn": {"x": 0.0, "y": 0.0, "yaw": 0.0},
                "boxes": [{"x": x, "y": 0.0, "half_x": half, "half_y": 1.0}],
            }
        ),
        "big.yaml",
    )
    with pytest.raises(WorldError, match=r"big.yaml: a grid of .* cells .*at most 1e\+08"):
        load_world(str(path))


def test_a_quaternion_of_huge_components_is_its_rotation(tmp_path):
    """(0, 0, 1e300, 1e300) is a quarter turn: its length overflowed to inf, the
    quaternion divided by it to zero and the box stood unturned."""
    pose = '<pose rotation_format="quat_xyzw">0 0 0.5 0 0 1e300 1e300</pose>'
    body = model("a", BOX.format("2 1 1")).replace("<pose>0 0 0 0 0 0</pose>", pose)
    world = load_world(str(write(tmp_path, sdf(body))))
    (box,) = world.boxes
    assert (box.half_x, box.half_y) == (1.0, 0.5)
    assert box.yaw == pytest.approx(math.pi / 2)


@pytest.mark.parametrize(
    ("geometry", "expect"),
    [
        # their bounds overflowed to inf: an OverflowError traceback before
        (BOX.format("1.79e308 1 1"), "<size>: model 'a' link 'link' collision 'c': <size> is more"),
        (cylinder(1.7e308), "<radius>: model 'a' link 'link' collision 'c': <radius> must be"),
        ("<sphere><radius>1e200</radius></sphere>", "<radius> must be positive and at most 1e+07"),
    ],
)
def test_a_body_of_1e308_m_is_refused_at_its_line(tmp_path, geometry, expect):
    path = write(tmp_path, sdf(model("a", geometry)))
    done = agv_here("world", str(path), "--save-map", str(tmp_path / "m"), cwd=tmp_path)
    flat = " ".join(done.stdout.split() + done.stderr.split())
    assert done.returncode == 2 and f"{path}:5: " in flat and expect in flat, flat
