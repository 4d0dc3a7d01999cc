"""Shared test fixtures."""

from __future__ import annotations

from pathlib import Path

import pytest

# /work/shared: the read-only test data next to the repository (never copied into it).
SHARED = Path(__file__).resolve().parents[2] / "shared"
ROS_MAPS = SHARED / "data" / "ros_maps"


@pytest.fixture
def shared() -> Path:
    """The shared data folder (``<repo>/../shared``)."""
    return SHARED


@pytest.fixture
def ros_maps() -> Path:
    """The folder holding the real ROS maps (``turtlebot3_world/``, ``aws_small_house/``)."""
    return ROS_MAPS
