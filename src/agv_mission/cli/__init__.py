"""The ``agv-mission`` command line: parse, call, print, set the exit code. Nothing else.

``commands`` lists the commands; each group lives in its own module (``runs``: run, validate,
schema; ``teleop``; ``bags``: map; ``regress``; ``service``: serve, submit) and prints
through ``console``.
"""

from agv_mission.cli.startup import quiet_until_started, started_as_program

# Quiet until a command sets its own handlers: the imports below take a while.
if started_as_program():
    quiet_until_started()

from agv_mission.cli.commands import app  # noqa: E402


def main() -> None:
    app()


__all__ = ["app", "main"]
