"""Shared test fixtures."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

# The real ROS maps, copied into the repository with their source and licence
# (tests/data/ros_maps/README.md), so a plain clone tests itself.
ROS_MAPS = Path(__file__).resolve().parent / "data" / "ros_maps"


@pytest.fixture
def run_cli():
    """The real command in this process (Typer's runner): exit code and all output."""
    from typer.testing import CliRunner

    from agv_mission.cli import app

    def run(args: list[str]) -> tuple[int, str]:
        r = CliRunner().invoke(app, args)
        assert r.exception is None or isinstance(r.exception, SystemExit), r.exception
        return r.exit_code, r.output

    return run


@pytest.fixture
def ros_maps() -> Path:
    """The folder holding the real ROS maps (``turtlebot3_world/``, ``aws_small_house/``)."""
    return ROS_MAPS


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    """A real headless chromium (Debian's, through Playwright), one per test module."""
    from playwright.sync_api import sync_playwright

    from service_server import launch_chromium

    with sync_playwright() as p:
        chromium = launch_chromium(p)
        yield chromium
        chromium.close()
