"""BehaviorTree.CPP v4 XML, both ways: a file the user wrote becomes the same
:class:`~agv_mission.missions.tree.NodeSpec` s a YAML tree does (each element keeps its
line), and any mission's tree is written back as XML with a ``<TreeNodesModel>`` that
Groot2 reads as its palette.

Each YAML type maps mechanically to a CamelCase ID (``reactive_fallback`` <->
``ReactiveFallback``); ports are attributes; structured values (poses, lists) are YAML
flow text. expat reads the file (it reports each element's line; ``xml.etree`` does not),
and expat refuses entity expansion attacks (billion laughs) itself.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any
from xml.parsers import expat
from xml.sax.saxutils import escape, quoteattr

import yaml

from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.tree import NodeSpec, TreeSource, Where, node_types

#: BT.CPP built-ins whose ID and ports are ours exactly: Groot2 knows them already.
BTCPP_BUILTINS = {
    "Sequence", "ReactiveSequence", "Fallback", "ReactiveFallback", "Parallel", "Inverter",
    "ForceSuccess", "ForceFailure", "KeepRunningUntilFailure", "Repeat", "RunOnce",
}  # fmt: skip
#: BT.CPP spellings read as ours.
ALIASES = {"RetryUntilSuccessful": "retry", "SetBlackboard": "set_blackboard"}
_KIND_TAGS = {"action": "Action", "condition": "Condition", "control": "Control",
              "decorator": "Decorator"}  # fmt: skip


def to_camel(node_type: str) -> str:
    return "".join(part.capitalize() for part in node_type.split("_"))


def to_snake(tag: str) -> str:
    return ALIASES.get(tag) or re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", tag).lower()


@dataclass
class _Element:
    tag: str
    attrs: dict[str, str]
    line: int
    children: list[_Element] = field(default_factory=list)


def _parse(text: str, file: str) -> _Element:
    parser = expat.ParserCreate()
    stack: list[_Element] = []
    root: list[_Element] = []

    def start(tag: str, attrs: dict[str, str]) -> None:
        element = _Element(tag, attrs, parser.CurrentLineNumber)
        (stack[-1].children if stack else root).append(element)
        stack.append(element)

    def end(tag: str) -> None:
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(text, True)
    except expat.ExpatError as exc:
        message = f"not well-formed XML: {expat.ErrorString(exc.code)} (column {exc.offset + 1})"
        raise MissionError([Problem(file, exc.lineno, "", message)]) from None
    except RecursionError:
        raise MissionError([Problem(file, None, "", "the XML nests too deeply")]) from None
    return root[0]


def parse_xml(text: str, file: str) -> TreeSource:
    """A BT.CPP v4 file: its ``<BehaviorTree>`` elements, the main one first."""
    root = _parse(text, file)
    if root.tag != "root":
        raise MissionError([Problem(file, root.line, "root", "a BT.CPP file's element is <root>")])
    fmt = root.attrs.get("BTCPP_format")
    if fmt is not None and fmt != "4":
        raise MissionError(
            [Problem(file, root.line, "root.BTCPP_format", f"format {fmt!r}; only 4 is read")]
        )
    trees: dict[str, NodeSpec] = {}
    problems: list[Problem] = []
    for element in root.children:
        if element.tag == "TreeNodesModel":
            continue
        if element.tag != "BehaviorTree":
            problems.append(
                Problem(
                    file, element.line, element.tag, "expected <BehaviorTree> or <TreeNodesModel>"
                )
            )
            continue
        tree_id = element.attrs.get("ID")
        path: tuple[str | int, ...] = ("BehaviorTree", tree_id or "?")
        if not tree_id:
            problems.append(Problem(file, element.line, "BehaviorTree.ID", "a tree needs an ID"))
            continue
        if len(element.children) != 1:
            problems.append(
                Problem(file, element.line, ".".join(map(str, path)),
                        f"a <BehaviorTree> holds one root node, got {len(element.children)}")
            )  # fmt: skip
            continue
        trees[tree_id] = _spec(element.children[0], path, file)
    if problems:
        raise MissionError(problems)
    if not trees:
        raise MissionError([Problem(file, root.line, "root", "no <BehaviorTree> in the file")])
    main = root.attrs.get("main_tree_to_execute") or next(iter(trees))
    if main not in trees:
        raise MissionError(
            [Problem(file, root.line, "root.main_tree_to_execute", f"no tree with ID {main!r}")]
        )
    return TreeSource(trees.pop(main), trees, {}, main)


def _spec(element: _Element, path: tuple[str | int, ...], file: str) -> NodeSpec:
    attrs = dict(element.attrs)
    name = attrs.pop("name", None)
    if element.tag == "SubTree":
        node_type = "subtree"
        attrs = {("id" if k == "ID" else k): v for k, v in attrs.items()}
    else:
        node_type = to_snake(element.tag)
    where = Where(file, path, element.line)
    spec = NodeSpec(node_type, where, name, attrs, {}, from_xml=True)
    spec.children = [_spec(child, path + (i,), file) for i, child in enumerate(element.children)]
    return spec


# --------------------------------------------------------------------- writing


def _flow(value: Any) -> str:
    if isinstance(value, str):
        return value
    return (
        yaml.safe_dump(value, default_flow_style=True, width=1 << 30)
        .strip()
        .removesuffix("\n...")
        .strip()
    )


def _write(spec: NodeSpec, depth: int, out: list[str]) -> None:
    pad = "  " * depth
    if spec.type == "subtree":
        attrs = {"ID": spec.ports.get("id", spec.ports.get("ID", ""))}
        attrs |= {k: v for k, v in spec.ports.items() if k not in ("id", "ID")}
        tag = "SubTree"
    else:
        tag = to_camel(spec.type)
        attrs = dict(spec.ports)
    if spec.name:
        attrs = {"name": spec.name, **attrs}
    text = "".join(f" {k}={quoteattr(_flow(v))}" for k, v in attrs.items())
    if not spec.children:
        out.append(f"{pad}<{tag}{text}/>")
        return
    out.append(f"{pad}<{tag}{text}>")
    for child in spec.children:
        _write(child, depth + 1, out)
    out.append(f"{pad}</{tag}>")


def export_xml(source: TreeSource) -> str:
    """``source`` as a BT.CPP v4 document with a ``<TreeNodesModel>`` of the types used."""
    out = [f'<root BTCPP_format="4" main_tree_to_execute={quoteattr(source.main_id)}>']
    for tree_id, spec in [(source.main_id, source.main), *source.trees.items()]:
        out.append(f"  <BehaviorTree ID={quoteattr(tree_id)}>")
        _write(spec, 2, out)
        out.append("  </BehaviorTree>")
    used: set[str] = set()
    for spec in [source.main, *source.trees.values()]:
        stack = [spec]
        while stack:
            s = stack.pop()
            used.add(s.type)
            stack.extend(s.children)
    out.append(nodes_model(used, indent=1))
    out.append("</root>")
    return "\n".join(out) + "\n"


def nodes_model(types: set[str] | None = None, indent: int = 0) -> str:
    """A ``<TreeNodesModel>`` (Groot2's palette) of ``types`` (default: every type)."""
    pad = "  " * indent
    out = [f"{pad}<TreeNodesModel>"]
    for info in node_types():
        if types is not None and info["type"] not in types:
            continue
        tag = to_camel(info["type"])
        if tag in BTCPP_BUILTINS:
            continue
        out.append(f"{pad}  <{_KIND_TAGS[info['kind']]} ID={quoteattr(tag)}>")
        for port in info["ports"]:
            direction = "output_port" if port["direction"] == "output" else "input_port"
            default = (
                "" if port["default"] is None else f" default={quoteattr(_flow(port['default']))}"
            )
            out.append(
                f"{pad}    <{direction} name={quoteattr(port['name'])} "
                f"type={quoteattr(port['type'])}{default}>{escape(port['description'])}"
                f"</{direction}>"
            )
        out.append(f"{pad}    <MetadataFields><Metadata description="
                   f"{quoteattr(info['description'])}/></MetadataFields>")  # fmt: skip
        out.append(f"{pad}  </{_KIND_TAGS[info['kind']]}>")
    out.append(f"{pad}</TreeNodesModel>")
    return "\n".join(out)
