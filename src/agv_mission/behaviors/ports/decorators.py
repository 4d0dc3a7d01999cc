"""The ports of the decorator nodes (:mod:`agv_mission.behaviors.decorators`)."""

from __future__ import annotations

from typing import Any, ClassVar, Literal

from pydantic import (
    Field,
)

from agv_mission.behaviors.ports.node import DecoratorPorts
from agv_mission.behaviors.ports.values import MAX_SIM_SECONDS


class InverterPorts(DecoratorPorts):
    """Success becomes failure and failure success."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Inverter"
    type: Literal["inverter"]


class ForceSuccessPorts(DecoratorPorts):
    """Succeeds whenever its child ends."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:ForceSuccess"
    type: Literal["force_success"]


class ForceFailurePorts(DecoratorPorts):
    """Fails whenever its child ends."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:ForceFailure"
    type: Literal["force_failure"]


class RetryPorts(DecoratorPorts):
    """Runs its child again after a failure, up to ``num_attempts`` tries in all."""

    btcpp_builtin: ClassVar[bool] = True
    xml_id: ClassVar[str | None] = "RetryUntilSuccessful"

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Retry"
    type: Literal["retry"]
    example: ClassVar[dict[str, Any] | None] = {"num_attempts": 2}
    num_attempts: int = Field(ge=-1, description="tries in all (-1: until it succeeds)")


class RepeatPorts(DecoratorPorts):
    """Runs its child again after a success, ``num_cycles`` times; fails on a failure."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Repeat"
    type: Literal["repeat"]
    example: ClassVar[dict[str, Any] | None] = {"num_cycles": 2}
    num_cycles: int = Field(ge=-1, description="successes to run (-1: until the time limit)")


class TimeoutPorts(DecoratorPorts):
    """Halts its child and fails after ``seconds`` of simulated time."""

    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"seconds": "msec"}
    xml_scale: ClassVar[dict[str, float]] = {"seconds": 1000.0}

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Timeout"
    type: Literal["timeout"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 1.0}
    seconds: float = Field(gt=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class DelayPorts(DecoratorPorts):
    """Waits ``seconds`` of simulated time (robot stopped), then runs its child."""

    btcpp_builtin: ClassVar[bool] = True
    xml_ports: ClassVar[dict[str, str]] = {"seconds": "delay_msec"}
    xml_scale: ClassVar[dict[str, float]] = {"seconds": 1000.0}

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:Delay"
    type: Literal["delay"]
    example: ClassVar[dict[str, Any] | None] = {"seconds": 0.2}
    seconds: float = Field(ge=0.0, le=MAX_SIM_SECONDS, description="simulated seconds")


class RateControllerPorts(DecoratorPorts):
    """Ticks its child at most ``hz`` times per simulated second (returns the last status
    between)."""

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:RateController"
    type: Literal["rate_controller"]
    example: ClassVar[dict[str, Any] | None] = {"hz": 5.0}
    hz: float = Field(gt=0.0, description="ticks per simulated second")


class KeepRunningUntilFailurePorts(DecoratorPorts):
    """Runs its child again after every success; fails when it fails."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:KeepRunningUntilFailure"
    type: Literal["keep_running_until_failure"]


class RunOncePorts(DecoratorPorts):
    """Runs its child once; afterwards returns its result (or succeeds: ``then_skip``)."""

    btcpp_builtin: ClassVar[bool] = True

    plugin: ClassVar[str] = "agv_mission.behaviors.decorators:RunOnce"
    type: Literal["run_once"]
    then_skip: bool = Field(True, description="after the first run: succeed (else its status)")
