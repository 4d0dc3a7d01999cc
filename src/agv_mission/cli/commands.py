"""The ``agv-mission`` commands, in the order ``--help`` lists them."""

from __future__ import annotations

import typer

from agv_mission.cli import bags, barn, regress, runs, service, teleop, trees, vda5050, worlds
from agv_mission.cli.startup import started

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Run YAML missions on a simulated differential-drive robot.",
)
app.callback()(started)
app.command()(runs.run)
app.command()(runs.validate)
app.command()(runs.schema)
app.add_typer(trees.app, name="tree")
app.command()(teleop.teleop)
app.command("map")(bags.map_)
app.command()(worlds.world)
app.command()(regress.regress)
app.command()(barn.barn)
app.command()(service.serve)
app.command()(service.submit)
app.add_typer(vda5050.app, name="vda5050")
