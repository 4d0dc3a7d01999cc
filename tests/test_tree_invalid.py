"""Malformed trees, in YAML and in BT.CPP XML: each is refused with the file, the line
(XML: the element's), the field path and a message that says what is wrong; the command
line exits 2 without a traceback."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from agv_mission.missions.load.errors import MissionError
from agv_mission.missions.load.loader import load_mission

HEAD = (
    "world: turtlebot3_world\n"  # 1
    "start: {x: -2.0, y: -0.5, yaw: 0.0}\n"  # 2
    "stack: {localization: {type: ground_truth}}\n"  # 3
)  # the tree starts on line 4


@dataclass(frozen=True)
class Case:
    name: str
    mission: str  # after HEAD
    line: int | None
    field: str
    message: str
    xml: str | None = None  # tree.xml beside the mission
    in_xml: bool = False  # the problem is placed in tree.xml


def _fanout() -> str:
    """Four levels of ten subtree calls: 10 000 leaves once expanded."""
    out = "trees:\n"
    for level in range(4):
        child = f"{{type: subtree, id: L{level + 1}}}" if level < 3 else "{type: stop}"
        out += f"  L{level}:\n    type: sequence\n    children: [{', '.join([child] * 10)}]\n"
    return out + "tree: {type: subtree, id: L0}\n"


XML_HEAD = '<root BTCPP_format="4" main_tree_to_execute="Main">\n'  # line 1

CASES = [
    Case("unknown type", "tree:\n  type: sequence\n  children:\n    - {type: fly}\n",
         7, "tree.children.0.type", "unknown node type 'fly'"),
    Case("unknown port", "tree:\n  type: sequence\n  children:\n    - {type: wait, seconds: 1,"
         " colour: red}\n", 7, "tree.children.0.colour", "unknown port 'colour'"),
    Case("missing port", "tree:\n  type: sequence\n  children:\n    - type: wait\n",
         7, "tree.children.0.seconds", "missing port 'seconds' of wait"),
    Case("wrong port type", "tree:\n  type: sequence\n  children:\n    - type: wait\n"
         "      seconds: soon\n", 8, "tree.children.0.seconds", "valid number"),
    Case("pose port missing y", "tree:\n  type: sequence\n  children:\n"
         "    - {type: go_to, pose: {x: 1.0}}\n", 7, "tree.children.0.pose", "y"),
    Case("decorator without child", "tree:\n  type: inverter\n", 4, "tree.child",
         "exactly one `child`"),
    Case("decorator with two children", "tree:\n  type: retry\n  num_attempts: 2\n"
         "  children: [{type: stop}, {type: stop}]\n", 4, "tree.child", "exactly one `child`, got 2"),
    Case("control without children", "tree: {type: sequence}\n", 4, "tree.children",
         "needs a list of `children`"),
    Case("control with no children", "tree:\n  type: fallback\n  children: []\n", 4,
         "tree.children", "needs a list of `children`"),
    Case("leaf with children", "tree:\n  type: stop\n  children: [{type: stop}]\n", 4,
         "tree.children", "has no children"),
    Case("node without type", "tree:\n  type: sequence\n  children:\n    - {name: x}\n", 7,
         "tree.children.0.type", "needs a `type`"),
    Case("child and children", "tree:\n  type: inverter\n  child: {type: stop}\n"
         "  children: [{type: stop}]\n", 4, "tree.children", "not both"),
    Case("unknown subtree", "tree:\n  type: sequence\n  children:\n"
         "    - {type: subtree, id: Nope}\n", 7, "tree.children.0.id", "unknown subtree id 'Nope'"),
    Case("subtree contains itself", "trees:\n  A:\n    type: sequence\n    children:\n"
         "      - {type: subtree, id: A}\ntree: {type: subtree, id: A}\n", 8,
         "trees.A.children.0.id", "contains itself (A -> A)"),
    Case("subtree contains itself indirectly", "trees:\n  A: {type: subtree, id: B}\n"
         "  B:\n    type: inverter\n    child: {type: subtree, id: A}\n"
         "tree: {type: subtree, id: A}\n", 8, "trees.B.child.id", "A -> B -> A"),
    Case("blackboard read nothing writes", "tree:\n  type: sequence\n  children:\n"
         "    - {type: navigate_to_pose, goal: '{target}'}\n", 7, "tree.children.0.goal",
         "reads blackboard entry 'target'"),
    Case("check_blackboard of an unwritten key", "tree:\n  type: sequence\n  children:\n"
         "    - {type: check_blackboard, key: ready, equals: true}\n", 7,
         "tree.children.0.key", "reads blackboard entry 'ready'"),
    Case("check_blackboard with two tests", "blackboard: {a: 1}\ntree:\n  type: sequence\n"
         "  children:\n    - {type: check_blackboard, key: a, less: 1, greater: 2}\n", 8,
         "tree.children.0", "exactly one of equals, less, greater"),
    Case("decorator port from the blackboard", "blackboard: {t: 3}\ntree:\n  type: timeout\n"
         "  seconds: '{t}'\n  child: {type: stop}\n", 7, "tree.seconds", "literals"),
    Case("over 10 000 nodes", _fanout(), 13, "trees.L2.children.8",
         "more than 10000 nodes"),
    Case("tasks and tree", "tasks: [{type: wander, duration: 1}]\ntree: {type: stop}\n", 5,
         "tree", "not both"),
    Case("tree names no XML file", "tree: patrol.txt\n", 4, "tree", "BT.CPP XML file"),
    Case("goal off the map", "tree:\n  type: sequence\n  children:\n"
         "    - {type: navigate_to_pose, goal: {x: 40.0, y: 0.0}}\n", 7,
         "tree.children.0.goal", "outside the map"),
    Case("unknown room", "tree:\n  type: sequence\n  children:\n    - {type: in_room, room: attic}\n",
         7, "tree.children.0.room", "unknown room 'attic'"),
    # ---- BT.CPP XML
    Case("xml not well-formed", "tree: tree.xml\n", 4, "", "not well-formed",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Sequence>\n  </BehaviorTree>\n</root>\n',
         in_xml=True),
    Case("xml unknown node", "tree: tree.xml\n", 4, "BehaviorTree.Main.0.type",
         "unknown node type 'fly_away'",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Sequence>\n      <FlyAway/>\n'
         "    </Sequence>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml missing port", "tree: tree.xml\n", 3, "BehaviorTree.Main.seconds",
         "missing port 'seconds'",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Wait/>\n  </BehaviorTree>\n</root>\n',
         in_xml=True),
    Case("xml wrong value", "tree: tree.xml\n", 3, "BehaviorTree.Main.seconds", "valid number",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Wait seconds="soon"/>\n'
         "  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml bad flow text", "tree: tree.xml\n", 3, "BehaviorTree.Main.goal",
         "as YAML flow text",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <NavigateToPose goal="{x: 1.0"/>\n'
         "  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml integer of 5000 digits", "tree: tree.xml\n", 3, "BehaviorTree.Main.num_cycles",
         "a number of 5000 digits (at most 4300)",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Repeat num_cycles="' + "9" * 5000
         + '">\n      <Stop/>\n    </Repeat>\n  </BehaviorTree>\n</root>\n', in_xml=True),
    Case("xml alias bomb in flow text", "tree: tree.xml\n", 3, "BehaviorTree.Main.goal",
         "aliases expand to more than",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <NavigateToPose goal="[&amp;a [1,1,1,1,1,1,1,1,1,1]'
         + "".join(f", &amp;{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 10)}]" for i in range(6))
         + ']"/>\n  </BehaviorTree>\n</root>\n', in_xml=True),
    Case("yaml alias bomb in subtrees", "trees:\n  a: &a {type: sequence, children: [{type: stop}]}\n"
         + "".join(f"  {chr(98 + i)}: &{chr(98 + i)} {{type: sequence, children: "
                   f"[{', '.join(['*' + chr(97 + i)] * 10)}]}}\n" for i in range(7))
         + "tree: *h\n", 12, "trees.h.children", "aliases expand to more than 2,000,000 values"),
    Case("xml unknown subtree", "tree: tree.xml\n", 4, "BehaviorTree.Main.0.id",
         "unknown subtree id 'Nope'",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Sequence>\n      <SubTree ID="Nope"/>\n'
         "    </Sequence>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml subtree contains itself", "tree: tree.xml\n", 7, "BehaviorTree.Loop.0.id",
         "contains itself",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <SubTree ID="Loop"/>\n  </BehaviorTree>\n'
         '  <BehaviorTree ID="Loop">\n    <Sequence>\n      <SubTree ID="Loop"/>\n'
         "    </Sequence>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml not UTF-8", "tree: tree.xml\n", 3, "",
         "not a UTF-8 text file (byte 0xff at column 20)",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Wait name="caf\udcff" wait_duration="1"/>\n'
         "  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml main tree calls itself", "tree: tree.xml\n", 7, "BehaviorTree.Loop.0.id",
         "subtree 'Main' contains itself (Main -> Loop -> Main)",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <SubTree ID="Loop"/>\n  </BehaviorTree>\n'
         '  <BehaviorTree ID="Loop">\n    <Sequence>\n      <SubTree ID="Main"/>\n'
         "    </Sequence>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml decorator with two children", "tree: tree.xml\n", 3, "BehaviorTree.Main.child",
         "exactly one `child`, got 2",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Inverter>\n      <Stop/>\n      <Stop/>\n'
         "    </Inverter>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml main tree missing", "tree: tree.xml\n", 1, "root.main_tree_to_execute",
         "no tree with ID 'Main'",
         XML_HEAD + '  <BehaviorTree ID="Other">\n    <Stop/>\n  </BehaviorTree>\n</root>\n',
         in_xml=True),
    Case("xml blackboard read nothing writes", "tree: tree.xml\n", 3, "BehaviorTree.Main.goal",
         "reads blackboard entry 'target'",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <NavigateToPose goal="{target}"/>\n'
         "  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml file missing", "tree: nowhere.xml\n", 4, "tree", "cannot read 'nowhere.xml'"),
    # ---- issue 34 (every malformed tree names its line) and 36 (BT.CPP, Nav2)
    Case("decorator given children", "tree:\n  type: sequence\n  children:\n"
         "    - type: inverter\n      children:\n        - {type: stop}\n", 8,
         "tree.children.0.children", "a decorator (inverter) takes `child:`"),
    Case("control given child", "tree:\n  type: sequence\n  child: {type: stop}\n", 6,
         "tree.children", "needs a list of `children`"),
    Case("if_then_else with one child", "tree:\n  type: if_then_else\n"
         "  children: [{type: stop}]\n", 6, "tree.children", "2 to 3 children, got 1"),
    Case("type not a string", "tree:\n  type: sequence\n  children:\n    - name: x\n"
         "      type: 5\n", 8, "tree.children.0.type", "needs a `type`"),
    Case("too deep", "tree:\n" + "".join("  " * (i + 1) + "type: inverter\n" + "  " * (i + 1)
         + "child:\n" for i in range(101)) + "  " * 102 + "type: stop\n", 204,
         "tree" + ".child" * 100, "nests deeper than 100"),
    Case("xml script", "tree: tree.xml\n", 4, "BehaviorTree.Main.0.type", "BT.CPP scripting",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Sequence>\n      <Script code="a:=1"/>\n'
         "    </Sequence>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml precondition attribute", "tree: tree.xml\n", 3, "BehaviorTree.Main._skipIf",
         "BT.CPP scripting",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <AlwaysSuccess _skipIf="a==1"/>\n'
         "  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml timeout msec not a number", "tree: tree.xml\n", 3, "BehaviorTree.Main.seconds",
         "valid number",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <Timeout msec="soon">\n'
         "      <AlwaysSuccess/>\n    </Timeout>\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("xml nests too deep", "tree: tree.xml\n", 3, "Inverter", "nests deeper than 500",
         XML_HEAD + '  <BehaviorTree ID="Main">\n' + "<Inverter>" * 600 + "<Stop/>"
         + "</Inverter>" * 600 + "\n  </BehaviorTree>\n</root>\n", in_xml=True),
    Case("navigator tree missing", "tree:\n  type: navigate_to_pose\n"
         "  goal: {x: -1.0, y: -0.5}\n  behavior_tree: nowhere.xml\n", 7,
         "tree.behavior_tree", "cannot read 'nowhere.xml'"),
    Case("navigator tree with an unknown port", "tree:\n  type: navigate_to_pose\n"
         "  goal: {x: -1.0, y: -0.5}\n  behavior_tree: tree.xml\n", 4,
         "BehaviorTree.Main.0.colour", "unknown port 'colour'",
         XML_HEAD + '  <BehaviorTree ID="Main">\n    <PipelineSequence>\n'
         '      <ComputePathToPose goal="{goal}" path="{path}" colour="red"/>\n'
         '      <FollowPath path="{path}"/>\n    </PipelineSequence>\n  </BehaviorTree>\n'
         "</root>\n", in_xml=True),
]  # fmt: skip


def _write(tmp_path: Path, case: Case) -> Path:
    path = tmp_path / "m.yaml"
    path.write_text(HEAD + case.mission)
    if case.xml is not None:
        (tmp_path / "tree.xml").write_text(case.xml, errors="surrogateescape")  # \udcff: 0xff
    return path


def test_the_corpus_is_large() -> None:
    assert len(CASES) >= 20
    assert sum(c.in_xml for c in CASES) >= 8


@pytest.mark.parametrize("case", CASES, ids=[c.name for c in CASES])
def test_malformed_tree_names_file_line_and_field(tmp_path: Path, case: Case) -> None:
    path = _write(tmp_path, case)
    with pytest.raises(MissionError) as info:
        load_mission(path)
    got = [(Path(p.file).name, p.line, p.field, p.message) for p in info.value.problems]
    file = "tree.xml" if case.in_xml else "m.yaml"
    assert any(
        f == file and line == case.line and field == case.field and case.message in message
        for f, line, field, message in got
    ), got


def test_validate_exits_2_without_a_traceback(tmp_path: Path) -> None:
    paths = []
    for i, case in enumerate(CASES[::4]):
        folder = tmp_path / str(i)
        folder.mkdir()
        paths.append(str(_write(folder, case)))
    proc = subprocess.run(
        [sys.executable, "-m", "agv_mission.cli", "validate", *paths],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stdout + proc.stderr
    for case in CASES[::4]:
        assert case.message in proc.stdout + proc.stderr
