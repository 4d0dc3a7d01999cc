"""BehaviorTree.CPP's own dialect (behaviour-trees.md, last section): its built-ins read
and written with their IDs and ports, an export's <TreeNodesModel> declaring our node types
only with BT.CPP's port type names, a file written for BT.CPP itself running, scripting
refused at its line, and the earlier spelling loading with a warning naming its line."""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from typer.testing import CliRunner

from agv_mission.cli import app
from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.load.tree_xml import TreeSpellingWarning, export_xml, parse_xml
from agv_mission.missions.run.runner import run_mission

REPO = Path(__file__).resolve().parents[1]
#: BT.CPP v4's built-ins (its src/bt_factory.cpp): never declared in a TreeNodesModel.
BUILTINS = {
    "Sequence", "SequenceWithMemory", "ReactiveSequence", "Fallback", "ReactiveFallback",
    "Parallel", "ParallelAll", "IfThenElse", "WhileDoElse", "Inverter", "ForceSuccess",
    "ForceFailure", "KeepRunningUntilFailure", "RetryUntilSuccessful", "Repeat", "Timeout",
    "Delay", "RunOnce", "AlwaysSuccess", "AlwaysFailure", "SetBlackboard", "Sleep", "SubTree",
}  # fmt: skip
PORT_TYPES = {"double", "int", "bool", "std::string"}

HEADER = (
    "world: turtlebot3_world\nrobot: burger\nstart: {x: -2.0, y: -0.5, yaw: 0.0}\n"
    "stack: {localization: {type: ground_truth}}\nlimits: {time: 30.0}\n"
)

#: Written for BT.CPP itself: its built-ins, its ports, its units (milliseconds).
BTCPP_FILE = """\
<?xml version="1.0"?>
<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <SequenceWithMemory name="all">
      <SetBlackboard value="2" output_key="rounds"/>
      <Repeat num_cycles="2">
        <Sleep msec="300"/>
      </Repeat>
      <RetryUntilSuccessful num_attempts="3">
        <Timeout msec="5000">
          <Delay delay_msec="200">
            <AlwaysSuccess/>
          </Delay>
        </Timeout>
      </RetryUntilSuccessful>
      <IfThenElse>
        <CheckBlackboard key="{rounds}" equals="2"/>
        <Log name="then" message="two rounds"/>
        <AlwaysFailure/>
      </IfThenElse>
      <ParallelAll max_failures="1">
        <Sleep msec="100"/>
        <AlwaysSuccess/>
      </ParallelAll>
    </SequenceWithMemory>
  </BehaviorTree>
</root>
"""


def _mission(tmp_path: Path, xml: str) -> Path:
    (tmp_path / "tree.xml").write_text(xml)
    path = tmp_path / "m.yaml"
    path.write_text(HEADER + "tree: tree.xml\n")
    return path


def _models(xml: str) -> list[ET.Element]:
    model = ET.fromstring(xml).find("TreeNodesModel")
    assert model is not None
    return list(model)


def test_export_writes_btcpp_ids_and_ports_and_declares_only_our_types() -> None:
    loaded = load_mission(REPO / "missions" / "wander_tree.yaml")
    xml = export_xml(loaded.tree.source)
    root = ET.fromstring(xml)
    timeout = next(root.iter("Timeout"))
    assert timeout.get("msec") == "60000" and "seconds" not in timeout.attrib
    declared = {m.get("ID") for m in _models(xml)}
    assert declared and not declared & BUILTINS, declared
    for model in _models(xml):
        for port in model:
            if port.tag in ("input_port", "output_port", "inout_port"):
                kind = port.get("type")
                assert kind in PORT_TYPES or kind.isidentifier(), (model.get("ID"), kind)


def test_the_palette_names_port_types_as_btcpp_does() -> None:
    out = CliRunner().invoke(app, ["tree", "nodes", "--xml"]).output
    models = _models(out)
    assert not {m.get("ID") for m in models} & BUILTINS
    types = {p.get("type") for m in models for p in m if p.tag.endswith("_port")}
    assert types <= PORT_TYPES | {"Pose", "Goal", "PoseList", "GoalList", "StringList",
                                  "AreaBounds"}, types  # fmt: skip
    assert not any("|" in t or "None" in t or "[" in t for t in types)


def test_a_file_written_for_btcpp_runs(tmp_path: Path) -> None:
    record = run_mission(load_mission(_mission(tmp_path, BTCPP_FILE)))
    assert record.status == "succeeded", record.reason
    assert [e["message"] for e in record.events if e["event"] == "log"] == ["two rounds"]
    # 2 x 300 ms sleeping, then a 200 ms delay, all simulated: the run lasts that long
    assert 0.8 <= record.sim_time <= 1.2


def test_export_and_reimport_keep_the_units(tmp_path: Path) -> None:
    source = parse_xml(BTCPP_FILE, "bt.xml")
    again = parse_xml(export_xml(source), "again.xml")
    timeout = again.main.children[2].children[0]
    assert timeout.type == "timeout" and timeout.ports == {"seconds": 5.0}
    assert ET.fromstring(export_xml(again)).find(".//Delay").get("delay_msec") == "200"


@pytest.mark.parametrize(
    ("body", "line", "what"),
    [
        ('<Sequence>\n      <Script code="x:=1"/>\n    </Sequence>', 4, "Script"),
        ('<Sequence>\n      <AlwaysSuccess _skipIf="x==1"/>\n    </Sequence>', 4, "_skipIf"),
        ('<Sequence>\n      <Precondition if="x" else="FAILURE">\n'
         '        <AlwaysSuccess/>\n      </Precondition>\n    </Sequence>', 4, "Precondition"),
    ],
    ids=["script", "skip-if", "precondition"],
)  # fmt: skip
def test_scripting_is_refused_at_its_line(body: str, line: int, what: str) -> None:
    xml = (
        f'<root BTCPP_format="4">\n  <BehaviorTree ID="M">\n    {body}\n  </BehaviorTree>\n</root>'
    )
    with pytest.raises(MissionError) as info:
        parse_xml(xml, "s.xml")
    (problem,) = info.value.problems
    assert problem.line == line and what in problem.message and "scripting" in problem.message


def test_the_earlier_spelling_loads_with_a_warning_naming_its_line(tmp_path: Path) -> None:
    old = (
        '<root BTCPP_format="4">\n  <BehaviorTree ID="M">\n    <Sequence>\n'
        '      <Timeout seconds="5">\n        <Wait seconds="0.2"/>\n      </Timeout>\n'
        '      <SetBlackboard key="done" value="1"/>\n    </Sequence>\n  </BehaviorTree>\n</root>\n'
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        record = run_mission(load_mission(_mission(tmp_path, old)))
    assert record.status == "succeeded"
    found = {(w.lineno, str(w.message).split(">")[0]) for w in caught
             if issubclass(w.category, TreeSpellingWarning)}  # fmt: skip
    assert {(4, "<Timeout seconds"), (5, "<Wait seconds"), (7, "<SetBlackboard key")} <= found
    assert all(str(w.filename).endswith("tree.xml") for w in caught
               if issubclass(w.category, TreeSpellingWarning))  # fmt: skip


def test_our_spelling_is_btcpp_s_for_nav2_s_actions() -> None:
    source = parse_xml(
        '<root BTCPP_format="4"><BehaviorTree ID="M"><Sequence>'
        '<Wait wait_duration="5"/><Spin spin_dist="1.57"/>'
        '<BackUp backup_dist="0.3" backup_speed="0.05"/><ClearEntireCostmap/>'
        "</Sequence></BehaviorTree></root>",
        "n.xml",
    )
    kids = source.main.children
    assert [k.type for k in kids] == ["wait", "spin", "back_up", "clear_costmap"]
    assert kids[0].ports == {"seconds": "5"} and kids[2].ports["distance"] == "0.3"
    out = ET.fromstring(export_xml(source))
    assert out.find(".//Wait").get("wait_duration") == "5"
    assert out.find(".//BackUp").get("backup_dist") == "0.3"
