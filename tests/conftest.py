"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

# The real ROS maps, copied into the repository with their source and licence
# (tests/data/ros_maps/README.md), so a plain clone tests itself.
ROS_MAPS = Path(__file__).resolve().parent / "data" / "ros_maps"


@pytest.fixture
def ros_maps() -> Path:
    """The folder holding the real ROS maps (``turtlebot3_world/``, ``aws_small_house/``)."""
    return ROS_MAPS
