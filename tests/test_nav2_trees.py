"""Nav2's navigator trees, as they ship (tests/nav2_trees: Humble, Jazzy, Rolling), run
unchanged on our planner, controller, costmap and recoveries; what their recoveries do
shows in the run's events; and every run's tree.btlog reads with an independent
FileLogger2 reader (written here from BT.CPP's format, not from our writer)."""

from __future__ import annotations

import json
import struct
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import open_run_dir, write_run
from agv_mission.missions.run.runner import run_mission

TREES = Path(__file__).parent / "nav2_trees"
WORLDS = Path(__file__).parent / "worlds"
THROUGH = "navigate_through_poses_w_replanning_and_recovery.xml"
#: Trees that navigate a goal (the rest: follow_point follows, odometry_calibration drives
#: a square).
NAVIGATORS = sorted(
    p
    for p in TREES.glob("*/*.xml")
    if p.name not in ("follow_point.xml", "odometry_calibration.xml")
)


def _house(tmp_path: Path, node: str, limit: float = 300.0, stack: str = "") -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(
        "world: small_house\nrobot: burger\nstart: livingroom\nseed: 1\n"
        f"{stack}tree:\n{node}limits: {{time: {limit}}}\n"
    )
    return path


def _to_pose(tree: Path, goal: str = "kitchen") -> str:
    return f"  type: navigate_to_pose\n  goal: {goal}\n  behavior_tree: {tree}\n"


def _through(tree: Path, goals: str = "[recreationroom, bedroom]") -> str:
    return f"  type: navigate_through_poses\n  goals: {goals}\n  behavior_tree: {tree}\n"


def _run(path: Path) -> tuple[dict, Path]:
    loaded = load_mission(path)
    run_dir = open_run_dir(path.parent / "runs", loaded)
    write_run(run_dir, loaded, run_mission(loaded, run_dir))
    return json.loads((run_dir / "result.json").read_text()), run_dir


@pytest.mark.parametrize("tree", NAVIGATORS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_every_shipped_navigator_tree_loads_unchanged(tmp_path: Path, tree: Path) -> None:
    node = _through(tree) if tree.name == THROUGH else _to_pose(tree)
    loaded = load_mission(_house(tmp_path, node))
    types = {n.type for _, n in loaded.tree.nodes()}
    assert "follow_path" in types and ({"compute_path_to_pose", "compute_path_through_poses"}
                                       & types)  # fmt: skip


@pytest.mark.parametrize("name", ["follow_point.xml", "odometry_calibration.xml"])
def test_the_other_shipped_trees_load_as_main_trees(tmp_path: Path, name: str) -> None:
    for folder in ("humble", "jazzy", "rolling"):
        (tmp_path / "tree.xml").write_text((TREES / folder / name).read_text())
        path = tmp_path / "m.yaml"
        path.write_text("world: small_house\nrobot: burger\nstart: livingroom\n"
                        "blackboard: {goal: kitchen}\ntree: tree.xml\n")  # fmt: skip
        assert load_mission(path).tree.count > 5


def test_jazzy_navigate_to_pose_drives_to_the_kitchen(tmp_path: Path) -> None:
    tree = TREES / "jazzy" / "navigate_to_pose_w_replanning_and_recovery.xml"
    result, run_dir = _run(_house(tmp_path, _to_pose(tree)))
    assert result["status"] == "succeeded", result["reason"]
    names = {n["name"]: n for n in result["tree"]}
    assert names["NavigateRecovery"]["status"] == "succeeded"
    assert names["compute_path_to_pose"]["started"] >= 5  # replanned at 1 Hz on the way
    reached = [e for e in result["events"] if e["event"] == "goal_reached"]
    assert reached and abs(reached[-1]["x"] - 7.0) < 0.1 and abs(reached[-1]["y"] + 2.0) < 0.1
    _check_btlog(run_dir / "tree.btlog", last_root=2)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("folder", "name", "through"),
    [
        ("humble", "navigate_to_pose_w_replanning_and_recovery.xml", False),
        ("rolling", "navigate_to_pose_w_replanning_and_recovery.xml", False),
        ("jazzy", "navigate_w_replanning_only_if_path_becomes_invalid.xml", False),
        ("jazzy", THROUGH, True),
        ("rolling", THROUGH, True),
    ],
)
def test_nav2_s_trees_drive_through_the_house(
    tmp_path: Path, folder: str, name: str, through: bool
) -> None:
    tree = TREES / folder / name
    node = (
        _through(tree)
        if through
        else "  type: sequence\n  children:\n"
        f"    - {{type: navigate_to_pose, goal: bedroom, behavior_tree: {tree}}}\n"
        f"    - {{type: navigate_to_pose, goal: kitchen, behavior_tree: {tree}}}\n"
    )
    result, _ = _run(_house(tmp_path, node, limit=400.0))
    assert result["status"] == "succeeded", result["reason"]
    goals = [
        (round(e["x"]), round(e["y"])) for e in result["events"] if e["event"] == "goal_reached"
    ]
    assert goals[-1] == ((-4, -2) if through else (7, -2)), goals


@pytest.mark.slow
def test_nav2_s_trees_drive_through_the_warehouse(tmp_path: Path) -> None:
    jazzy = TREES / "jazzy"
    path = tmp_path / "w.yaml"
    path.write_text(
        "world: warehouse\nrobot: burger\nstart: dock\nseed: 1\ntree:\n  type: sequence\n"
        "  children:\n"
        f"    - {{type: navigate_to_pose, goal: cross_aisle, behavior_tree: "
        f"{jazzy / 'navigate_to_pose_w_replanning_and_recovery.xml'}}}\n"
        f"    - {{type: navigate_through_poses, goals: [east_aisle, back_aisle], "
        f"behavior_tree: {jazzy / THROUGH}}}\n"
        "limits: {time: 600}\n"
    )
    result, _ = _run(path)
    assert result["status"] == "succeeded", result["reason"]


def test_the_tree_s_recoveries_show_in_the_events(tmp_path: Path) -> None:
    """A controller that can never make progress (1 m within 0.5 s): Humble's tree runs
    its recoveries (clear, spin, wait, back up, round robin) six times, then fails."""
    tree = TREES / "humble" / "navigate_to_pose_w_replanning_and_recovery.xml"
    stack = "stack: {navigation: {progress_distance: 1.0, progress_timeout: 0.5}}\n"
    result, run_dir = _run(_house(tmp_path, _to_pose(tree), stack=stack))
    assert result["status"] == "failed"
    events = result["events"]
    tree_recoveries = [e for e in events if e["event"] == "tree_recovery"]
    assert {e["node"] for e in tree_recoveries} == {"FollowPath", "NavigateRecovery"}
    assert max(e["retry"] for e in tree_recoveries if e["node"] == "NavigateRecovery") == 6
    kinds = {e["kind"] for e in events if e["event"] == "recovery"}
    assert {"clear_costmap", "spin", "back_up"} <= kinds
    assert result["metrics"]["navigation"]["recoveries"]["spin"] >= 1
    _check_btlog(run_dir / "tree.btlog", last_root=3)


def test_a_navigator_tree_s_problems_name_its_file_and_line(tmp_path: Path) -> None:
    (tmp_path / "bad.xml").write_text(
        '<root BTCPP_format="4" main_tree_to_execute="M">\n  <BehaviorTree ID="M">\n'
        '    <PipelineSequence>\n      <ComputePathToPose goal="{goal}" path="{path}" colour="red"/>\n'
        '      <FollowPath path="{path}"/>\n    </PipelineSequence>\n  </BehaviorTree>\n</root>\n'
    )
    with pytest.raises(MissionError) as info:
        load_mission(_house(tmp_path, _to_pose(Path("bad.xml"))))
    (problem,) = info.value.problems
    assert (
        Path(problem.file).name == "bad.xml" and problem.line == 4 and "colour" in problem.message
    )
    with pytest.raises(MissionError) as info:
        load_mission(_house(tmp_path, _to_pose(Path("missing.xml"))))
    (problem,) = info.value.problems
    assert problem.line == 8 and problem.field == "tree.behavior_tree"


# ----------------------------------------------------------------- FileLogger2, read here


def read_btlog(path: Path) -> tuple[ET.Element, int, list[tuple[int, int, int]]]:
    """BT.CPP's FileLogger2 file: (the tree's XML, the start in microseconds, transitions
    as (microseconds since the start, uid, status))."""
    data = path.read_bytes()
    magic = b"BTCPP4-FileLogger2"
    assert data[: len(magic)] == magic
    at = len(magic)
    assert data[at] == 1  # protocol
    (size,) = struct.unpack_from("<i", data, at + 1)
    xml = ET.fromstring(data[at + 5 : at + 5 + size].decode("utf-8"))
    at += 5 + size
    (start,) = struct.unpack_from("<q", data, at)
    at += 8
    body = data[at:]
    assert len(body) % 9 == 0
    transitions = []
    for i in range(0, len(body), 9):
        usec = int.from_bytes(body[i : i + 6], "little")
        uid, status = struct.unpack_from("<HB", body, i + 6)
        transitions.append((usec, uid, status))
    return xml, start, transitions


def _check_btlog(path: Path, last_root: int) -> None:
    xml, start, transitions = read_btlog(path)
    assert xml.tag == "root" and start == 0
    nodes = [e for tree in xml.findall("BehaviorTree") for e in tree.iter() if e is not tree]
    uids = [int(e.get("_uid")) for e in nodes]
    assert all(e.get("_uid") for e in nodes) and len(set(uids)) == len(uids)
    assert sorted(uids) == list(range(1, len(uids) + 1))
    times = [t for t, _, _ in transitions]
    assert transitions and times == sorted(times)
    assert {uid for _, uid, _ in transitions} <= set(uids)
    assert {s for _, _, s in transitions} <= {0, 1, 2, 3, 4}
    root = [s for _, uid, s in transitions if uid == 1]
    assert root[0] == 1 and root[-1] == last_root  # the root ran, and ended as the run did
    assert not {m.get("ID") for m in xml.find("TreeNodesModel")} & {"Sequence", "Timeout"}


def test_a_fleet_writes_a_btlog_per_robot(tmp_path: Path) -> None:
    path = tmp_path / "f.yaml"
    path.write_text(
        f"world: {WORLDS / 'fleet_door.yaml'}\nseed: 11\n"
        "stack: {localization: {type: ground_truth}, local_planner: {type: pure_pursuit}}\n"
        "robots:\n"
        "  - {name: west, robot: burger, start: {x: -3.0, y: 0.0, yaw: 0.0},\n"
        "     tree: {type: sequence, children: [{type: wait, seconds: 0.5}]}}\n"
        "  - {name: east, robot: burger, start: {x: 3.0, y: 0.0, yaw: 3.1416},\n"
        "     tree: {type: timeout, seconds: 5, child: {type: wait, seconds: 0.3}}}\n"
        "limits: {time: 20}\n"
    )
    result, run_dir = _run(path)
    assert result["status"] == "succeeded", result["reason"]
    for robot in ("west", "east"):
        xml, _, transitions = read_btlog(run_dir / f"tree.{robot}.btlog")
        assert [s for _, uid, s in transitions if uid == 1][-1] == 2
    xml, _, _ = read_btlog(run_dir / "tree.east.btlog")
    assert xml.find(".//Timeout").get("msec") == "5000"
    assert not (run_dir / "tree.btlog").exists()
