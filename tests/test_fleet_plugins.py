"""The fleet slots: built-ins announced as entry points, the conformance check catches a
plugin that breaks the contract, and the ``fleet:`` block validates like ``stack:``."""

from __future__ import annotations

from typing import Literal

import pytest
from pydantic import ValidationError

from agv_mission.fleet.base import Assignment, TrafficDecision, TrafficUpdate
from agv_mission.fleet.traffic import ReservationTraffic
from agv_mission.missions.load.schema.fleet import Fleet
from agv_mission.plugin_check import PluginCheckError, check_plugin
from agv_mission.registry import PluginConfig, registry


def test_the_fleet_slots_hold_the_builtins_lazily() -> None:
    assert registry.names("dispatcher") == ["nearest_idle", "quickest_finish"]
    assert registry.names("traffic") == ["reservations"]
    assert registry.get("traffic", "reservations") is ReservationTraffic


class _Reckless:
    """A traffic plugin that lets everyone go: robots would meet head-on."""

    class Config(PluginConfig):
        type: Literal["reckless"] = "reckless"

    def __init__(self, config: Config) -> None:
        self.config = config

    def decide(self, t, robots):  # type: ignore[no-untyped-def]
        return TrafficUpdate({r.name: TrafficDecision() for r in robots})

    def stats(self):  # type: ignore[no-untyped-def]
        return {"waits": {"count": 0, "time": 0.0}, "deadlocks": 0}


class _Lenient:
    """A dispatcher that gives a task to a robot out of service, and never refuses."""

    class Config(PluginConfig):
        type: Literal["lenient"] = "lenient"

    def __init__(self, config: Config) -> None:
        self.config = config

    def assign(self, task, robots, travel_time):  # type: ignore[no-untyped-def]
        return Assignment(robots[-1].name, 0.0)


class _Forgetful:
    """A traffic plugin without ``stats``."""

    class Config(PluginConfig):
        type: Literal["forgetful"] = "forgetful"

    def decide(self, t, robots):  # type: ignore[no-untyped-def]
        return TrafficUpdate({})


def test_check_plugin_names_what_a_fleet_plugin_breaks() -> None:
    with pytest.raises(PluginCheckError, match="both let go into each other"):
        check_plugin(_Reckless)
    with pytest.raises(PluginCheckError, match="chose 'out'"):
        check_plugin(_Lenient)
    with pytest.raises(PluginCheckError, match="missing stats"):
        check_plugin(_Forgetful, "traffic")


def test_the_fleet_block_defaults_and_validates() -> None:
    fleet = Fleet()
    assert (fleet.dispatcher.type, fleet.traffic.type) == ("quickest_finish", "reservations")
    tuned = Fleet.model_validate(
        {"traffic": {"horizon": 6.0}, "dispatcher": {"type": "nearest_idle"}}
    )
    assert tuned.traffic.type == "reservations" and tuned.traffic.horizon == 6.0
    assert tuned.dispatcher.type == "nearest_idle"
    with pytest.raises(ValidationError, match="horizn"):
        Fleet.model_validate({"traffic": {"horizn": 6.0}})
    with pytest.raises(ValidationError, match="quickest_finish"):
        Fleet.model_validate({"dispatcher": {"type": "auction"}})
    with pytest.raises(ValidationError, match="margin"):
        Fleet.model_validate({"traffic": {"margin": -0.1}})


def test_a_built_fleet_plugin_comes_from_its_config() -> None:
    fleet = Fleet.model_validate({"traffic": {"margin": 0.2}})
    traffic = registry.create("traffic", fleet.traffic)
    assert isinstance(traffic, ReservationTraffic) and traffic.config.margin == 0.2
    assert type(registry.create("dispatcher", fleet.dispatcher)).__name__ == (
        "QuickestFinishDispatcher"
    )
