"""BehaviorTree.CPP v4 XML, both ways: a file the user wrote becomes the same
:class:`~agv_mission.missions.load.tree_spec.NodeSpec` s a YAML tree does (each element keeps its
line), and any mission's tree is written back as XML with a ``<TreeNodesModel>`` that
Groot2 reads as its palette.

The dialect is BT.CPP's: a node type's ports model names its XML ID and the attributes
of ports spelled otherwise in YAML (``timeout``'s ``seconds`` is BT.CPP's ``Timeout
msec``, ``wait``'s Nav2's ``Wait wait_duration``, ``retry`` is ``RetryUntilSuccessful``);
other types map mechanically to CamelCase (``reactive_fallback`` <->
``ReactiveFallback``); structured values (poses, lists) are YAML flow text. The earlier
spelling (``<Timeout seconds>``, ``<Wait seconds>``, ``<SetBlackboard key>``, ``<Retry>``)
still loads, with a :class:`TreeSpellingWarning` naming the line. BT.CPP's scripting is
refused at its line. expat reads the file (it reports each element's line;
``xml.etree`` does not), and expat refuses entity expansion attacks (billion laughs).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from functools import cache
from typing import Any
from xml.parsers import expat
from xml.sax.saxutils import escape, quoteattr

import yaml

from agv_mission.behaviors.ports import blackboard_key
from agv_mission.missions.load.errors import MissionError, Problem
from agv_mission.missions.load.node_types import node_types
from agv_mission.missions.load.tree_spec import SLOT, NodeSpec, TreeSource, Where
from agv_mission.registry import UnknownPluginError, registry

#: Old names still read: BT.CPP's (quietly) and our earlier spelling (with a warning).
ALIASES = {"SequenceStar": "sequence_with_memory"}
OLD_TAGS = {"Retry": "retry", "Recovery": "recovery", "ClearCostmap": "clear_costmap"}
#: BT.CPP's scripting, which is not run here.
SCRIPT_TAGS = {"Script", "ScriptCondition", "Precondition"}
SCRIPT_ATTRIBUTES = {"_skipIf", "_failureIf", "_successIf", "_while", "_onSuccess",
                     "_onFailure", "_onHalted", "_post"}  # fmt: skip
_KIND_TAGS = {"action": "Action", "condition": "Condition", "control": "Control",
              "decorator": "Decorator"}  # fmt: skip


#: Elements nested deeper are refused (a tree that deep is a mistake; recursion stays bounded).
MAX_DEPTH = 500


class TreeSpellingWarning(UserWarning):
    """An XML tree in the earlier spelling (it loads; BT.CPP and Groot2 would not)."""


def to_camel(node_type: str) -> str:
    return "".join(part.capitalize() for part in node_type.split("_"))


@cache
def _dialect() -> dict[str, str]:
    """XML ID -> node type, for every registered type."""
    out: dict[str, str] = {}
    for name in registry.names(SLOT):
        try:
            config = registry.config(SLOT, name)
        except UnknownPluginError:
            continue
        out[getattr(config, "xml_id", None) or to_camel(name)] = name
    return out


def xml_id(node_type: str) -> str:
    """The XML element of ``node_type``."""
    try:
        config = registry.config(SLOT, node_type)
    except UnknownPluginError:
        return to_camel(node_type)
    return getattr(config, "xml_id", None) or to_camel(node_type)


def to_snake(tag: str) -> str:
    guess = re.sub(r"(?<=[a-z0-9])(?=[A-Z])", "_", tag).lower()
    if guess in registry.names(SLOT) and xml_id(guess) == tag:
        return guess  # a type's own spelling: only its config is loaded, not every type's
    known = _dialect()
    if tag in known:
        return known[tag]
    return ALIASES.get(tag) or OLD_TAGS.get(tag) or guess


def _config(node_type: str) -> Any:
    try:
        return registry.config(SLOT, node_type)
    except UnknownPluginError:
        return None


def warn(file: str, line: int, message: str) -> None:
    """A warning naming the file and line (Python's warnings show that line's text)."""
    warnings.warn_explicit(message, TreeSpellingWarning, file, line)


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
        if len(stack) >= MAX_DEPTH:
            message = f"the XML nests deeper than {MAX_DEPTH} elements"
            raise MissionError([Problem(file, parser.CurrentLineNumber, tag, message)])
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
    where = Where(file, path, element.line)
    if element.tag in SCRIPT_TAGS:
        raise MissionError([where.problem(
            f"<{element.tag}> is BT.CPP scripting, which is not supported: use node types "
            "(check_blackboard, set_blackboard, ...)", "type")])  # fmt: skip
    scripted = sorted(SCRIPT_ATTRIBUTES & set(element.attrs))
    if scripted:
        raise MissionError([where.problem(
            f"{scripted[0]} is BT.CPP scripting (a pre/post condition), which is not "
            "supported: use a condition node", scripted[0])])  # fmt: skip
    attrs = dict(element.attrs)
    name = attrs.pop("name", None)
    if element.tag == "SubTree":
        node_type = "subtree"
        attrs = {("id" if k == "ID" else k): v for k, v in attrs.items()}
    else:
        node_type = to_snake(element.tag)
        if element.tag in OLD_TAGS:
            warn(file, element.line, f"<{element.tag}> is the earlier spelling; BT.CPP and "
                 f"Nav2 write <{xml_id(node_type)}>")  # fmt: skip
        attrs = _ports_from_xml(node_type, attrs, file, element)
    spec = NodeSpec(node_type, where, name, attrs, {}, from_xml=True)
    spec.children = [_spec(child, path + (i,), file) for i, child in enumerate(element.children)]
    return spec


def _ports_from_xml(
    node_type: str, attrs: dict[str, str], file: str, element: _Element
) -> dict[str, Any]:
    """Attributes as our ports: BT.CPP's names and units read; our earlier names kept,
    with a warning."""
    config = _config(node_type)
    if config is None:
        return attrs
    ours = {v: k for k, v in config.xml_ports.items()}
    out: dict[str, Any] = {}
    for attr, value in attrs.items():
        port = ours.get(attr)
        if port is None:
            if attr in config.xml_ports:
                warn(file, element.line, f"<{element.tag} {attr}> is the earlier spelling; "
                     f"BT.CPP and Nav2 write {config.xml_ports[attr]}")  # fmt: skip
            out[attr] = value
            continue
        scale = config.xml_scale.get(port)
        if scale and blackboard_key(value) is None:
            try:
                out[port] = float(value) / scale
            except ValueError:
                out[port] = value  # reported by the port's validation
            continue
        out[port] = value
    return out


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
        tag = xml_id(spec.type)
        attrs = _ports_to_xml(spec.type, spec.ports)
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


def _ports_to_xml(node_type: str, ports: dict[str, Any]) -> dict[str, Any]:
    config = _config(node_type)
    if config is None:
        return dict(ports)
    out: dict[str, Any] = {}
    for port, value in ports.items():
        scale = config.xml_scale.get(port)
        if scale and isinstance(value, (int, float)) and not isinstance(value, bool):
            scaled = value * scale
            value = int(round(scaled)) if abs(scaled - round(scaled)) < 1e-6 else scaled
        out[config.xml_ports.get(port, port)] = value
    return out


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
    for info in node_types(types):
        config = _config(info["type"])
        if config is None or config.btcpp_builtin:
            continue
        tag = xml_id(info["type"])
        out.append(f"{pad}  <{_KIND_TAGS[info['kind']]} ID={quoteattr(tag)}>")
        names = config.xml_ports
        for port in info["ports"]:
            direction = "output_port" if port["direction"] == "output" else "input_port"
            scale = config.xml_scale.get(port["name"])
            if scale and isinstance(port["default"], (int, float)):
                port = {**port, "default": port["default"] * scale}
            default = (
                "" if port["default"] is None else f" default={quoteattr(_flow(port['default']))}"
            )
            out.append(
                f"{pad}    <{direction} name={quoteattr(names.get(port['name'], port['name']))} "
                f"type={quoteattr(port['type'])}{default}>{escape(port['description'])}"
                f"</{direction}>"
            )
        out.append(f"{pad}    <MetadataFields><Metadata description="
                   f"{quoteattr(info['description'])}/></MetadataFields>")  # fmt: skip
        out.append(f"{pad}  </{_KIND_TAGS[info['kind']]}>")
    out.append(f"{pad}</TreeNodesModel>")
    return "\n".join(out)
