"""The configuration blocks of the fleet plugins (``fleet.dispatcher``, ``fleet.traffic``).

They live apart from the plugins, as the planners' do, so that validating a mission or
printing the schema imports no shapely geometry: each config names its plugin class by
import path (``plugin``), loaded only when a run builds it.
"""

from __future__ import annotations

from typing import ClassVar, Literal

from pydantic import Field

from agv_mission.registry import PluginConfig


class QuickestFinishConfig(PluginConfig):
    """``dispatcher`` block ``type: quickest_finish`` (the default): a task goes to the
    robot that would finish it soonest, counting the work it already holds (Open-RMF's
    default bidding: the lowest cost bid, cost = the time the robot would be done)."""

    plugin: ClassVar[str] = "agv_mission.fleet.dispatch:QuickestFinishDispatcher"

    type: Literal["quickest_finish"] = "quickest_finish"


class NearestIdleConfig(PluginConfig):
    """``dispatcher`` block ``type: nearest_idle``: a task goes to the idle robot nearest
    its first goal (by travel time); when none is idle, to the robot free soonest (the
    plain 'closest free vehicle' rule of simple fleet managers)."""

    plugin: ClassVar[str] = "agv_mission.fleet.dispatch:NearestIdleDispatcher"

    type: Literal["nearest_idle"] = "nearest_idle"


class ReservationsConfig(PluginConfig):
    """``traffic`` block ``type: reservations`` (the default): every control step each
    robot reserves the space its plan sweeps over the next ``horizon`` seconds; a robot
    whose sweep meets another's reservation or body waits, or goes only as far as stays
    clear; cycles of waits and waits on parked robots are deadlocks, broken by a
    ``yield`` (a robot drives to a pose out of the other's way and waits there) or a
    ``replan`` around the other's reserved space."""

    plugin: ClassVar[str] = "agv_mission.fleet.traffic:ReservationTraffic"

    type: Literal["reservations"] = "reservations"
    horizon: float = Field(
        4.0,
        gt=0,
        le=60.0,
        description="seconds of plan a robot reserves: a prefix of max_speed * horizon + "
        "lookahead metres (4 s: a waffle at 0.26 m/s reserves 1.3 m, about three body "
        "lengths, ahead of it)",
    )
    lookahead: float = Field(
        0.3, ge=0, le=10.0, description="metres reserved beyond max_speed * horizon"
    )
    margin: float = Field(
        0.15,
        ge=0,
        le=2.0,
        description="metres kept between two robots' footprints (both estimates' error, a "
        "few cm each with amcl, plus one control period of travel)",
    )
    deadlock_delay: float = Field(
        1.0,
        ge=0,
        le=60.0,
        description="seconds a cycle of waits (or a wait on a parked robot) must stand "
        "before it is broken: robots still braking are not in a deadlock",
    )
    wait_timeout: float = Field(
        15.0,
        gt=0,
        le=3600.0,
        description="seconds a robot may wait for the same robot before the wait is "
        "treated as a deadlock (first a replan around it, then a yield): nobody waits "
        "forever",
    )
    replan_patience: float = Field(
        3.0,
        gt=0,
        le=600.0,
        description="seconds a replan around a parked robot may take to clear the way "
        "before the parked robot is asked to yield",
    )
    yield_timeout: float = Field(
        60.0,
        gt=0,
        le=3600.0,
        description="seconds a yielding robot waits at its detour pose at most before it "
        "resumes its own goal (a new conflict is then resolved afresh)",
    )
    detour_radius: float = Field(
        15.0,
        gt=0,
        le=200.0,
        description="metres around a yielding robot searched for a detour pose",
    )
