"""The ports of BehaviorTree.CPP v4's built-ins that have no older node type of ours:
``SequenceWithMemory``, ``ParallelAll``, ``IfThenElse``, ``WhileDoElse``,
``AlwaysSuccess``, ``AlwaysFailure`` and ``Sleep`` (BT.CPP's ``src/bt_factory.cpp``).
Their XML is BT.CPP's own, and an exported ``<TreeNodesModel>`` never declares them."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import Field

from agv_mission.behaviors.ports.node import ControlPorts, NodePorts
from agv_mission.behaviors.ports.values import MAX_SIM_SECONDS


class SequenceWithMemoryPorts(ControlPorts):
    """Ticks children in order; after a failure it resumes at the failed child, not the
    first (BT.CPP's SequenceWithMemory; SequenceStar is its old name)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:SequenceWithMemory"
    type: Literal["sequence_with_memory"]
    btcpp_builtin: ClassVar[bool] = True


class ParallelAllPorts(ControlPorts):
    """Ticks every child until all have ended; fails when ``max_failures`` of them failed."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:ParallelAll"
    type: Literal["parallel_all"]
    btcpp_builtin: ClassVar[bool] = True
    max_failures: int = Field(1, ge=-1, description="failures that fail it (-1: all)")


class IfThenElsePorts(ControlPorts):
    """The first child decides, once: success runs the second, failure the third (or
    fails without one)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:IfThenElse"
    type: Literal["if_then_else"]
    btcpp_builtin: ClassVar[bool] = True
    children_range: ClassVar[tuple[int, int] | None] = (2, 3)


class WhileDoElsePorts(ControlPorts):
    """The first child decides every tick: success runs the second, failure the third (or
    fails without one), halting the other branch."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:WhileDoElse"
    type: Literal["while_do_else"]
    btcpp_builtin: ClassVar[bool] = True
    children_range: ClassVar[tuple[int, int] | None] = (2, 3)


class AlwaysSuccessPorts(NodePorts):
    """Succeeds."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:AlwaysSuccess"
    type: Literal["always_success"]
    btcpp_builtin: ClassVar[bool] = True


class AlwaysFailurePorts(NodePorts):
    """Fails."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:AlwaysFailure"
    type: Literal["always_failure"]
    btcpp_builtin: ClassVar[bool] = True


class SleepPorts(NodePorts):
    """Runs for ``seconds`` of simulated time, the robot standing (BT.CPP's Sleep, msec)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.btcpp:Sleep"
    type: Literal["sleep"]
    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"seconds": "msec"}
    xml_scale: ClassVar[dict[str, float]] = {"seconds": 1000.0}
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.2}
    seconds: float = Field(ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")
