"""Behaviour trees as configuration: the node library's semantics on simulated time, one
assembly for tasks, YAML trees and BT.CPP XML (the same run whichever the user wrote),
result.json's ``tree``, and a third-party node type registered at run time."""

from __future__ import annotations

import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import py_trees
import pytest
import yaml
from py_trees.common import Status
from typer.testing import CliRunner

from agv_mission.behaviors.check import sample_context
from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.ports import NodePorts
from agv_mission.cli import app
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.tree_assembly import assemble
from agv_mission.missions.load.tree_spec import TreeSource, yaml_spec
from agv_mission.missions.load.tree_xml import export_xml, parse_xml
from agv_mission.missions.run.behaviour_tree import MissionTree, build_tree
from agv_mission.missions.run.runner import run_mission
from agv_mission.navigation.handle import RobotHandle
from agv_mission.plugin_check import PluginCheckError, check_plugin
from agv_mission.registry import registry
from cli_in_process import agv
from mission_texts import mission_file, tb3_mission

STEP = 0.05


def _tree(text: str, context: TreeContext, blackboard: dict | None = None) -> MissionTree:
    data = yaml.safe_load(text)
    source = TreeSource(yaml_spec(data, ("tree",), "t.yaml", {}), {}, blackboard or {})
    context.blackboard.update(source.blackboard)
    return build_tree(assemble(source), context)


def _tick(tree: MissionTree, context: TreeContext, n: int = 1) -> None:
    """``n`` control steps, or fewer: a tree that ends is not started again."""
    for _ in range(n):
        context.handle.stop()
        tree.root.tick_once()
        context.handle.state.time += STEP
        if tree.root.status is not Status.RUNNING:
            return


def _node(tree: MissionTree, name: str) -> py_trees.behaviour.Behaviour:
    return next(r.behaviour for r in tree.records if r.node.name == name)


def test_reactive_sequence_halts_the_action_its_condition_guards() -> None:
    ctx = sample_context()
    tree = _tree(
        """
type: reactive_sequence
children:
  - {type: check_blackboard, key: go, equals: true}
  - {type: drive, name: ahead, v: 0.1, seconds: 100}
""",
        ctx,
        {"go": True},
    )
    _tick(tree, ctx, 3)
    assert tree.root.status is Status.RUNNING and ctx.handle.command == (0.1, 0.0)
    ctx.blackboard["go"] = False
    _tick(tree, ctx)
    assert tree.root.status is Status.FAILURE
    assert _node(tree, "ahead").status is Status.INVALID  # halted
    assert ctx.handle.command == (0.0, 0.0)


def test_reactive_fallback_lets_a_higher_priority_branch_take_over() -> None:
    ctx = sample_context()
    tree = _tree(
        """
type: reactive_fallback
children:
  - type: reactive_sequence
    children:
      - {type: time_elapsed, seconds: 0.5}
      - {type: drive, name: turn, w: 0.4, seconds: 100}
  - {type: drive, name: ahead, v: 0.1, seconds: 100}
""",
        ctx,
    )
    _tick(tree, ctx, 5)
    assert _node(tree, "ahead").status is Status.RUNNING
    _tick(tree, ctx, 6)  # past 0.5 s of simulated time
    assert _node(tree, "turn").status is Status.RUNNING
    assert _node(tree, "ahead").status is Status.INVALID
    assert ctx.handle.command == (0.0, 0.4)  # turning, not driving ahead
    report = {n["name"]: n for n in tree.report()}
    assert report["ahead"]["status"] == "halted" and report["ahead"]["started"] == 1
    assert report["ahead"]["running_time"] == pytest.approx(0.5, abs=0.06)


def test_timeout_delay_and_rate_controller_count_simulated_time() -> None:
    ctx = sample_context()
    tree = _tree(
        """
type: timeout
seconds: 1.0
child: {type: delay, seconds: 0.5, child: {type: drive, name: d, v: 0.1, seconds: 100}}
""",
        ctx,
    )
    _tick(tree, ctx, 10)
    assert _node(tree, "d").status is Status.INVALID  # still delayed
    _tick(tree, ctx, 5)
    assert _node(tree, "d").status is Status.RUNNING
    _tick(tree, ctx, 5)
    assert tree.root.status is Status.RUNNING  # the tick at t = 0.95 s
    _tick(tree, ctx)
    assert tree.root.status is Status.FAILURE  # at t = 1.0 s
    assert tree.root.feedback_message == "timed out after 1 s"

    ctx = sample_context()
    tree = _tree(
        """
type: repeat
num_cycles: -1
child: {type: rate_controller, hz: 2.0, child: {type: wait, name: w, seconds: 0.3}}
""",
        ctx,
    )
    _tick(tree, ctx, 20)
    assert tree.report()[2]["started"] == 2  # ticked every 0.5 s while it waits


def test_retry_repeat_run_once_and_force() -> None:
    ctx = sample_context()
    tree = _tree(
        """
type: sequence
children:
  - type: force_success
    child: {type: retry, num_attempts: 3, child: {type: check_blackboard, name: c, key: k, equals: 2}}
  - {type: repeat, num_cycles: 3, child: {type: log, name: tick, message: once more}}
  - {type: run_once, child: {type: log, name: first, message: first}}
""",
        ctx,
        {"k": 1},
    )
    _tick(tree, ctx, 12)
    report = {n["name"]: n for n in tree.report()}
    assert report["c"]["started"] == 3 and report["c"]["status"] == "failed"
    assert report["tick"]["started"] == 3
    assert report["first"]["started"] == 1
    assert tree.root.status is Status.SUCCESS


def test_retry_with_minus_one_attempts_tries_until_it_succeeds() -> None:
    """BT.CPP's ``RetryUntilSuccessful num_attempts="-1"``: tries for as long as it takes
    (py_trees' own Retry would fail at the first failure)."""
    ctx = sample_context()
    tree = _tree(
        """
type: sequence
children:
  - type: retry
    num_attempts: -1
    child:
      type: sequence
      children:
        - {type: wait, name: pause, seconds: 0.2}
        - {type: check_blackboard, name: c, key: k, equals: 2}
  - {type: log, name: done, message: done}
""",
        ctx,
        {"k": 1},
    )
    _tick(tree, ctx, 60)
    report = {n["name"]: n for n in tree.report()}
    assert report["c"]["started"] >= 10 and report["c"]["status"] == "failed"
    assert tree.root.status is Status.RUNNING
    ctx.blackboard["k"] = 2
    _tick(tree, ctx, 6)
    assert tree.root.status is Status.SUCCESS
    assert {n["name"]: n for n in tree.report()}["done"]["started"] == 1


def test_parallel_pipeline_round_robin_and_recovery() -> None:
    ctx = sample_context()
    tree = _tree(
        """
type: parallel
success_count: 1
children:
  - {type: wait, name: short, seconds: 0.2}
  - {type: wait, name: long, seconds: 5}
""",
        ctx,
    )
    _tick(tree, ctx, 6)
    assert tree.root.status is Status.SUCCESS
    assert {n["name"]: n["status"] for n in tree.report()}["long"] == "halted"

    ctx = sample_context()
    tree = _tree(
        """
type: recovery
number_of_retries: 2
children:
  - {type: check_blackboard, name: ok, key: fixed, equals: true}
  - {type: set_blackboard, name: fix, key: fixed, value: true}
""",
        ctx,
        {"fixed": False},
    )
    _tick(tree, ctx, 4)
    assert tree.root.status is Status.SUCCESS
    report = {n["name"]: n for n in tree.report()}
    assert report["ok"]["started"] == 2 and report["fix"]["started"] == 1

    ctx = sample_context()
    tree = _tree(
        """
type: repeat
num_cycles: 4
child:
  type: round_robin
  children:
    - {type: log, name: a, message: a}
    - {type: log, name: b, message: b}
""",
        ctx,
    )
    _tick(tree, ctx, 10)
    assert [e["message"] for e in ctx.handle.events] == ["a", "b", "a", "b"]

    ctx = sample_context()
    tree = _tree(
        """
type: pipeline_sequence
children:
  - {type: drive, name: first, v: 0.1, seconds: 0.2}
  - {type: wait, name: second, seconds: 1}
""",
        ctx,
    )
    _tick(tree, ctx, 3)
    assert _node(tree, "first").status is Status.RUNNING


# ------------------------------------------------------------------ whole runs

GO = "{type: go_to, pose: {x: -1.4, y: -0.5, yaw: 0.0}}"


def _trajectory(path: Path) -> np.ndarray:
    record = run_mission(load_mission(path))
    assert record.status == "succeeded", record.reason
    return record.trajectory


def test_tasks_yaml_tree_and_exported_xml_are_the_same_run(tmp_path: Path) -> None:
    text = tb3_mission(GO, limits="{time: 20.0}")
    tasks = mission_file(tmp_path, text, "tasks")
    tree_text = text.replace(
        f"tasks:\n  - {GO}\n", f"tree:\n  type: sequence\n  children: [{GO}]\n"
    )
    tree = mission_file(
        tmp_path, tree_text.replace("type: sequence", "type: sequence\n  name: mission"), "tree"
    )
    exported = subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", "tree", "export", str(tasks)],
        capture_output=True, text=True, check=True, timeout=120,
    ).stdout  # fmt: skip
    root = ET.fromstring(exported)
    assert (
        root.get("BTCPP_format") == "4"
        and root.find("TreeNodesModel/Action[@ID='GoTo']") is not None
    )
    (tmp_path / "exported.xml").write_text(exported)
    xml = mission_file(tmp_path, text.replace(f"tasks:\n  - {GO}\n", "tree: exported.xml\n"), "xml")
    a, b, c = _trajectory(tasks), _trajectory(tree), _trajectory(xml)
    assert len(a) > 20
    assert np.array_equal(a, b) and np.array_equal(a, c)


def test_result_reports_the_tree_and_keeps_task_reports(tmp_path: Path) -> None:
    text = tb3_mission(GO, limits="{time: 20.0}").replace(
        f"tasks:\n  - {GO}\n",
        f"""blackboard: {{home: {{x: -2.0, y: -0.5, yaw: 3.14}}}}
tree:
  type: sequence
  name: out and back
  children:
    - {GO}
    - {{type: set_blackboard, key: "{{back}}", value: true}}
    - {{type: navigate_to_pose, name: home, goal: "{{home}}"}}
    - {{type: check_blackboard, key: "{{back}}", equals: true}}
""",
    )
    record = run_mission(load_mission(mission_file(tmp_path, text)))
    assert record.status == "succeeded", record.reason
    tree = record.extras["tree"]
    assert [n["path"] for n in tree] == ["/", "/0", "/1", "/2", "/3"]
    assert [n["type"] for n in tree] == [
        "sequence", "go_to", "set_blackboard", "navigate_to_pose", "check_blackboard",
    ]  # fmt: skip
    assert all(n["status"] == "succeeded" and n["started"] == 1 for n in tree)
    assert tree[2]["running_time"] == 0.0 and tree[3]["running_time"] > 1.0
    assert tree[0]["running_time"] == pytest.approx(record.sim_time, abs=0.11)
    [task] = record.tasks
    assert task["type"] == "go_to" and task["status"] == "succeeded"


class Blink(py_trees.behaviour.Behaviour):
    """Log ``times`` events, one a tick (a third-party node)."""

    class Config(NodePorts):
        type: Literal["blink"] = "blink"
        times: int = 2
        example: ClassVar[dict] = {"times": 3}

    def __init__(self, name: str, handle: RobotHandle, times: int = 2):
        super().__init__(name)
        self.handle, self.times, self.count = handle, times, 0

    def initialise(self) -> None:
        self.count = 0

    def update(self) -> Status:
        self.count += 1
        self.handle.log("blink", n=self.count)
        return Status.SUCCESS if self.count >= self.times else Status.RUNNING


class Forgetful(Blink):
    """Takes no ``times``: breaks the slot's contract."""

    class Config(NodePorts):
        type: Literal["forgetful"] = "forgetful"
        times: int = 2

    def __init__(self, name: str, handle: RobotHandle):
        super().__init__(name, handle)


def test_a_third_party_node_registered_at_run_time(tmp_path: Path) -> None:
    check_plugin(Blink)
    with pytest.raises(PluginCheckError, match="does not take the port 'times'"):
        check_plugin(Forgetful, "behavior")
    registry.register("behavior", "blink")(Blink)
    text = tb3_mission(GO, limits="{time: 5.0}").replace(
        f"tasks:\n  - {GO}\n", "tree: {type: sequence, children: [{type: blink, times: 4}]}\n"
    )
    record = run_mission(load_mission(mission_file(tmp_path, text)))
    assert record.status == "succeeded"
    assert [e["n"] for e in record.events if e["event"] == "blink"] == [1, 2, 3, 4]
    nodes = agv("tree", "nodes", "--xml")  # in this process; ``tree export`` above starts one
    assert nodes.returncode == 0, nodes.stderr
    listed = nodes.stdout
    ids = {e.get("ID") for e in ET.fromstring(listed).iter() if e.get("ID")}
    assert {"GoTo", "NavigateToPose", "RangeAheadBelow", "Patrol", "ComputePathToPose"} <= ids
    assert not {"Timeout", "Sequence", "RetryUntilSuccessful"} & ids  # BT.CPP's own: not declared


def test_xml_subtree_ports_remap_to_the_callers_entries() -> None:
    source = parse_xml(
        """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <SubTree ID="Say" text="{greeting}"/>
      <SubTree ID="Say" text="literal words"/>
      <SubTree ID="Say" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Say"><Log message="{text}"/></BehaviorTree>
</root>""",
        "t.xml",
    )
    source.blackboard = {"greeting": "hello", "text": "auto"}
    ctx = sample_context()
    ctx.blackboard.update(source.blackboard)
    tree = build_tree(assemble(source), ctx)
    _tick(tree, ctx, 3)
    assert [e["message"] for e in ctx.handle.events] == ["hello", "literal words", "auto"]
    again = parse_xml(export_xml(source), "again.xml")
    assert again.trees.keys() == source.trees.keys()


def test_registry_lists_every_contract_node_type() -> None:
    names = set(registry.names("behavior"))
    assert {
        "sequence", "reactive_sequence", "fallback", "reactive_fallback", "parallel",
        "pipeline_sequence", "round_robin", "recovery", "inverter", "force_success",
        "force_failure", "retry", "repeat", "timeout", "delay", "rate_controller",
        "keep_running_until_failure", "run_once", "in_room", "at_pose", "range_ahead_below",
        "person_near", "time_elapsed", "check_blackboard", "is_path_clear", "go_to", "patrol",
        "visit_rooms", "record_room", "wander", "map_area", "teleop", "navigate_to_pose",
        "drive", "stop", "wait", "spin", "back_up", "clear_costmap", "set_blackboard", "log",
    } <= names  # fmt: skip


def test_the_dashboard_stream_shows_the_users_node_names_and_statuses() -> None:
    from agv_mission.missions.run.samples import tree_nodes

    ctx = sample_context()
    tree = _tree(
        """
type: sequence
name: errand
children:
  - {type: wait, name: pause, seconds: 0.1}
  - {type: drive, name: creep forward, v: 0.05, seconds: 1}
""",
        ctx,
    )
    _tick(tree, ctx, 4)
    shown = {(n.name, n.depth, n.status) for n in tree_nodes(tree.root)}
    assert {("errand", 0, "RUNNING"), ("pause", 1, "SUCCESS")} <= shown
    assert ("creep forward", 1, "RUNNING") in shown


def test_a_tree_that_repeats_forever_succeeds_at_the_time_limit(tmp_path: Path) -> None:
    forever = tb3_mission(GO, limits="{time: 3.0}").replace(
        f"tasks:\n  - {GO}\n",
        "tree: {type: repeat, num_cycles: -1, child: {type: wait, seconds: 0.5}}\n",
    )
    record = run_mission(load_mission(mission_file(tmp_path, forever, "forever")))
    assert record.status == "succeeded" and record.sim_time == pytest.approx(3.0)
    assert record.extras["tree"][1]["started"] == 6
    bounded = forever.replace("num_cycles: -1", "num_cycles: 100")
    record = run_mission(load_mission(mission_file(tmp_path, bounded, "bounded")))
    assert record.status == "failed" and "time limit" in (record.reason or "")


CONTRACT_BATTERY_PATROL = """\
name: battery-patrol
world: small_house
robot: burger
seed: 3
simulation: {battery_level: 0.302}
stack: {localization: {type: ground_truth}}
limits: {time: 90.0}
blackboard:
  home: {x: 0.0, y: 0.0, yaw: 0.0}
trees:
  Recharge:
    type: sequence
    children:
      - {type: dock, dock: "{dock}"}
      - {type: charge, until: 0.95}
      - {type: undock}
tree:
  type: repeat
  num_cycles: -1
  child:
    type: reactive_fallback
    children:
      - type: sequence
        children:
          - {type: is_battery_low, min_battery: 0.3}
          - {type: subtree, id: Recharge, dock: charger}
      - type: patrol
        waypoints: [{x: 1.0, y: 2.0, yaw: 0.0}, {x: -3.0, y: 1.0, yaw: 1.57}]
"""


def test_the_contracts_battery_patrol_runs_its_subtree(tmp_path: Path) -> None:
    """The contract's own example: a subtree with a remapped port, under a reactive guard;
    the battery falls below 0.3 on the patrol and the Recharge subtree docks the robot."""
    path = tmp_path / "battery_patrol.yaml"
    path.write_text(CONTRACT_BATTERY_PATROL)
    result = CliRunner().invoke(app, ["run", str(path), "--output", str(tmp_path / "runs")])
    assert result.exit_code == 0, result.output  # repeat -1 runs to the time limit
    [run_dir] = (tmp_path / "runs").iterdir()
    doc = json.loads((run_dir / "result.json").read_text())
    events = [e["event"] for e in doc["events"]]
    assert "docked" in events and "charging" in events, events
    assert doc["metrics"]["battery"]["minimum"] < 0.3
    assert any(node["type"] == "subtree" for node in doc["tree"]), doc["tree"]
