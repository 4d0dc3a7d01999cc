"""``agv-mission tree``: a mission's tree as BT.CPP v4 XML (for Groot2), and the node
library with its ports."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from agv_mission.cli.console import Overrides, PipeSafeStdout, invalid, out
from agv_mission.missions.load.errors import MissionError

app = typer.Typer(
    no_args_is_help=True,
    help="Behaviour trees: export a mission's tree as BT.CPP XML; list the node types.",
)


@app.command()
def export(
    mission: Annotated[Path, typer.Argument(help="a mission file")],
    set_: Overrides = [],  # noqa: B006 (typer reads the default)
) -> None:
    """Print the mission's tree (a tasks: list expanded) as BT.CPP v4 XML with a
    <TreeNodesModel>, so Groot2 opens it."""
    from agv_mission.missions.load.loader import load_mission
    from agv_mission.missions.load.tree_xml import export_xml

    try:
        loaded = load_mission(mission, set_)
    except MissionError as exc:
        raise invalid(exc) from None
    if loaded.tree is None:
        out.print(f"{mission}: no tree (a setup without tasks)")
        raise typer.Exit(2)
    PipeSafeStdout().write(export_xml(loaded.tree.source))


@app.command()
def nodes(
    xml: Annotated[
        bool, typer.Option("--xml", help="as a Groot2 palette (<TreeNodesModel>)")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="as JSON")] = False,
) -> None:
    """List every node type with its ports (name, direction, type, default, description)."""
    from agv_mission.missions.load.node_types import node_types
    from agv_mission.missions.load.tree_xml import nodes_model

    if xml:
        PipeSafeStdout().write('<root BTCPP_format="4">\n' + nodes_model(indent=1) + "\n</root>\n")
        return
    types = node_types()
    if as_json:
        PipeSafeStdout().write(json.dumps(types, indent=2) + "\n")
        return
    lines = []
    for info in types:
        lines.append(f"{info['type']} ({info['kind']}{', task' if info['task'] else ''}): "
                     f"{info['description']}")  # fmt: skip
        for p in info["ports"]:
            default = "required" if p["required"] else f"default {json.dumps(p['default'])}"
            lines.append(f"    {p['name']} [{p['direction']}, {p['type']}, {default}]: "
                         f"{p['description']}")  # fmt: skip
    PipeSafeStdout().write("\n".join(lines) + "\n")
