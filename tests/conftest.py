"""Shared test fixtures."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

# The real ROS maps, copied into the repository with their source and licence
# (tests/data/ros_maps/README.md), so a plain clone tests itself.
ROS_MAPS = Path(__file__).resolve().parent / "data" / "ros_maps"


def pytest_configure(config: pytest.Config) -> None:
    # xdist declares this marker only when it is loaded: said here for ``-p no:xdist`` too.
    config.addinivalue_line(
        "markers", "xdist_group(name): the module's tests share one worker (make test's loadgroup)"
    )


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
