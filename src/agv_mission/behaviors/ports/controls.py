"""The ports of the control nodes (:mod:`agv_mission.behaviors.controls`)."""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import (
    Field,
)

from agv_mission.behaviors.ports.node import ControlPorts


class SequencePorts(ControlPorts):
    """Ticks its children in order; fails on the first failure, resumes at the running one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Sequence"
    type: Literal["sequence"]


class ReactiveSequencePorts(ControlPorts):
    """Re-ticks every earlier child each tick: conditions guard a running action."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:ReactiveSequence"
    type: Literal["reactive_sequence"]


class FallbackPorts(ControlPorts):
    """Succeeds on the first child that succeeds; resumes at the running one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Fallback"
    type: Literal["fallback"]


class ReactiveFallbackPorts(ControlPorts):
    """Re-ticks earlier children every tick; one that starts running halts the later one."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:ReactiveFallback"
    type: Literal["reactive_fallback"]


class ParallelPorts(ControlPorts):
    """Ticks every child each tick; succeeds or fails on counts of children (BT.CPP v4)."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Parallel"
    type: Literal["parallel"]
    success_count: int = Field(-1, ge=-1, description="successes that succeed it (-1: all)")
    failure_count: int = Field(1, ge=-1, description="failures that fail it (-1: all)")


class PipelineSequencePorts(ControlPorts):
    """Nav2's PipelineSequence: re-ticks every child up to the running one."""

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:PipelineSequence"
    type: Literal["pipeline_sequence"]


class RoundRobinPorts(ControlPorts):
    """Nav2's RoundRobin: one child per tick in turn; succeeds on the first success."""

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:RoundRobin"
    type: Literal["round_robin"]
    wrap_around: bool = Field(False, description="Nav2's: accepted (children are tried in turn)")


class RecoveryPorts(ControlPorts):
    """Nav2's RecoveryNode: two children, the action and its recovery, retried."""

    xml_id: ClassVar[str | None] = "RecoveryNode"
    children_range: ClassVar[tuple[int, int] | None] = (2, 2)

    plugin: ClassVar[str] = "agv_mission.behaviors.controls:Recovery"
    type: Literal["recovery"]
    number_of_retries: int = Field(1, ge=0, description="recoveries before it fails")
