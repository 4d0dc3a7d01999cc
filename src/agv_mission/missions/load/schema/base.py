"""The building blocks of a mission file: strict models, poses (planar or ROS style), the
bounds on what scales memory or time, and ``start`` (a pose or a room label)."""

from __future__ import annotations

from typing import Annotated, Union

from pydantic import Discriminator, Tag

from agv_mission.behaviors.ports import (  # noqa: F401 (the schema's names)
    MAX_LOOPS,
    MAX_ROOMS,
    MAX_SIM_SECONDS,
    MAX_WAYPOINTS,
    QUATERNION_TOLERANCE,
    ROS_POSE_SCHEMA,
    Orientation,
    Pose,
    Position,
    StrictModel,
)

# Bounds on what scales memory or time (a mission over them is refused, not run).
MAX_TASKS = 1000
MAX_OBSTACLES = 1000
MAX_FAULTS = 100
MAX_NAME_LENGTH = 100  # a path component of the run directory, with a timestamp after it
MAX_TREE_NODES = 10_000  # a tree's nodes once its subtrees are expanded


StartSpec = Annotated[
    Union[Annotated[Pose, Tag("Pose")], Annotated[str, Tag("str")]],  # noqa: UP007
    Discriminator(lambda v: "str" if isinstance(v, str) else "Pose"),
]
