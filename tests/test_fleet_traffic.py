"""The traffic layer's algorithm on real maps with real cost_grid plans: robots advanced
kinematically by its decisions never touch, never wait forever, and all arrive."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agv_mission.fleet.configs import ReservationsConfig
from agv_mission.fleet.traffic import ReservationTraffic
from agv_mission.geometry import Pose2D as P
from agv_mission.maps.builtin_worlds import warehouse
from fleet_kinematic import BURGER, WAFFLE, KinematicFleet, world

MARGIN = ReservationsConfig().margin


def _check(fleet: KinematicFleet, ok: bool) -> None:
    assert ok, f"not every robot arrived by t = {fleet.t}: " + ", ".join(
        f"{b.name} at {b.pose} with {len(b.goals)} goals left" for b in fleet.bots
    )
    # footprints never touch; they keep at least half the margin (the other half is the
    # slack a robot already too close may use to move off alongside)
    assert fleet.min_gap >= MARGIN / 2 - 0.02, fleet.min_gap
    assert fleet.longest_wait() < ReservationsConfig().wait_timeout


def test_head_on_in_a_one_robot_wide_aisle_one_yields_and_both_arrive() -> None:
    fleet = KinematicFleet(world("fleet_aisle"))
    fleet.add("a", P(-4.5, 0.5, 0.0), [P(4.5, -0.5, 0.0)])
    fleet.add("b", P(4.5, 0.5, math.pi), [P(-4.5, -0.5, math.pi)])
    _check(fleet, fleet.run(200.0))
    cycles = [e for e in fleet.kinds("deadlock") if e["kind"] == "cycle"]
    assert cycles and sorted(cycles[0]["robots"]) == ["a", "b"]
    yielder = cycles[0]["robot"]
    assert "yield" in fleet.decisions[yielder]
    assert [e["robot"] for e in fleet.kinds("yield_end")][:1] == [yielder]
    # the detour is out of the aisle (|x| > 3), where the other robot's path does not go
    assert abs(cycles[0]["detour"]["x"]) > 3.0
    waits = fleet.traffic.stats()["waits"]
    assert waits["count"] == len(fleet.kinds("wait")) and waits["time"] > 0.0


def test_head_on_without_traffic_control_would_collide() -> None:
    """The aisle test is a real test: robots that ignore each other do meet."""
    fleet = KinematicFleet(world("fleet_aisle"))
    fleet.add("a", P(-4.5, 0.5, 0.0), [P(4.5, -0.5, 0.0)])
    fleet.add("b", P(4.5, 0.5, math.pi), [P(-4.5, -0.5, math.pi)])
    fleet.traffic = _Blind()
    fleet.run(60.0)
    assert fleet.min_gap < 0.0


def test_four_way_crossing() -> None:
    fleet = KinematicFleet(world("fleet_crossing"))
    fleet.add("north", P(0.0, 4.5, -math.pi / 2), [P(0.0, -4.5, 0.0)])
    fleet.add("south", P(0.0, -4.5, math.pi / 2), [P(0.0, 4.5, 0.0)], WAFFLE)
    fleet.add("east", P(4.5, 0.0, math.pi), [P(-4.5, 0.0, 0.0)])
    fleet.add("west", P(-4.5, 0.0, 0.0), [P(4.5, 0.0, 0.0)])
    _check(fleet, fleet.run(200.0))
    assert fleet.traffic.stats()["waits"]["count"] > 0  # they did meet in the middle


def test_narrow_door_between_rooms() -> None:
    fleet = KinematicFleet(world("fleet_door"))
    fleet.add("a1", P(-3.0, 1.0, 0.0), [P(3.0, -1.0, 0.0)])
    fleet.add("a2", P(-3.0, -1.0, 0.0), [P(3.0, 1.0, 0.0)])
    fleet.add("b1", P(3.0, 1.0, math.pi), [P(-3.0, -1.0, 0.0)])
    fleet.add("b2", P(3.0, -1.0, math.pi), [P(-3.0, 1.0, 0.0)], WAFFLE)
    _check(fleet, fleet.run(200.0))
    assert fleet.traffic.stats()["deadlocks"] >= 1  # head-on in the door, broken


def test_more_robots_than_parking_spots_the_parked_ones_make_way() -> None:
    """Two bays, four robots: the two without a bay stand in the bays' mouths; they are
    asked to step aside (after a replan round them finds no way) and the others park."""
    fleet = KinematicFleet(world("fleet_parking"))
    fleet.add("a", P(-2.0, -1.5, 0.0), [P(1.2, 1.9, math.pi / 2)])
    fleet.add("b", P(2.0, -1.5, 0.0), [P(-1.2, 1.9, math.pi / 2)])
    c = fleet.add("c", P(-1.2, 1.1, 0.0), [])
    d = fleet.add("d", P(1.2, 1.1, 0.0), [])
    _check(fleet, fleet.run(200.0))
    parked = [e for e in fleet.kinds("deadlock") if e["kind"] == "parked"]
    assert {e["action"] for e in parked} == {"replan", "yield"}
    assert {e["robot"] for e in parked if e["action"] == "yield"} == {"c", "d"}
    for bot, (x, y) in ((c, (-1.2, 1.1)), (d, (1.2, 1.1))):
        assert math.hypot(bot.pose.x - x, bot.pose.y - y) > 0.1  # it moved out of the way
    assert fleet.bots[0].pose.distance_to(P(1.2, 1.9)) < 0.1
    assert fleet.bots[1].pose.distance_to(P(-1.2, 1.9)) < 0.1


def test_a_robot_waiting_on_a_stuck_robot_does_not_wait_forever() -> None:
    """A robot that keeps its plan but never moves is no deadlock the graph sees (it does
    not wait); the wait on it outlasts ``wait_timeout`` and the waiter replans round it."""
    traffic = ReservationTraffic(ReservationsConfig(wait_timeout=5.0))
    fleet = KinematicFleet(world("fleet_crossing"), traffic)
    fleet.add("a", P(0.0, -4.5, math.pi / 2), [P(0.0, 4.5, 0.0)])
    broken = fleet.add("broken", P(0.0, 1.5, math.pi / 2), [P(0.0, 4.5, 0.0)])
    broken.stuck = True
    fleet.run(200.0)
    assert not fleet.bots[0].goals  # a arrived, the long way round
    assert fleet.min_gap >= MARGIN / 2 - 0.02
    timeouts = [e for e in fleet.kinds("deadlock") if e["kind"] == "timeout"]
    assert timeouts and timeouts[0]["action"] == "replan" and timeouts[0]["robot"] == "a"
    first_wait = fleet.kinds("wait")[0]
    assert first_wait["robot"] == "a" and first_wait["for"] == "broken"
    assert timeouts[0]["t"] - first_wait["t"] == pytest.approx(5.0, abs=0.15)


@pytest.mark.slow  # 11 s; the scenario suite's fleet runs cover the traffic
@pytest.mark.parametrize("seed", [3])
def test_ten_robots_in_the_warehouse(seed: int) -> None:
    """Ten robots (a third of them waffles) from the dock to two aisle positions each and
    back, on the 30 x 50 m warehouse."""
    fleet = KinematicFleet(warehouse())
    rng = np.random.default_rng(seed)
    for i in range(10):
        start = P(-13.0 + 26.0 * i / 9, -21.5 + (i % 2) * 1.5, math.pi / 2)
        goals = []
        for _ in range(2):
            y = float(rng.uniform(-16.0, 16.0))
            goals.append(P(3.6 * int(rng.integers(-3, 3)) + 1.8, y if abs(y) > 3 else 10.0))
        fleet.add(f"r{i}", start, [*goals, start], WAFFLE if i % 3 == 0 else BURGER)
    _check(fleet, fleet.run(900.0))
    assert all(len(b.arrived) == 3 for b in fleet.bots)


def test_decisions_and_events_are_reproducible() -> None:
    runs = []
    for _ in range(2):
        fleet = KinematicFleet(world("fleet_door"))
        fleet.add("a1", P(-3.0, 1.0, 0.0), [P(3.0, -1.0, 0.0)])
        fleet.add("b1", P(3.0, 1.0, math.pi), [P(-3.0, -1.0, 0.0)])
        fleet.run(120.0)
        runs.append((fleet.events, fleet.decisions, [b.pose for b in fleet.bots]))
    assert runs[0] == runs[1]


class _Blind(ReservationTraffic):
    """Lets everyone go (what a fleet without traffic control does)."""

    def decide(self, t, robots):  # type: ignore[no-untyped-def]
        update = super().decide(t, robots)
        update.decisions = {r.name: type(update.decisions[r.name])() for r in robots}
        return update


def test_a_robot_standing_too_close_to_another_may_still_move_away() -> None:
    """Nearer another's space than its own radius already (the depot livelock: two robots
    braking 0.35 m apart each yielding in turn, neither ever let go): moving away is
    granted; moving closer is not."""
    from agv_mission.fleet.base import TrafficRobot

    traffic = ReservationTraffic()
    stands = TrafficRobot("stands", P(-0.27, 0.0, 0.0), 0.105, 0.22)
    away = TrafficRobot(
        "away", P(0.0, 0.0, 0.0), 0.105, 0.22, path=np.array([[0.0, 0.0], [1.5, 0.0]])
    )
    decision = traffic.decide(0.0, [stands, away]).decisions["away"]
    assert decision.action == "go" and (decision.limit is None or decision.limit > 0.5)
    closer = TrafficRobot(
        "closer", P(0.0, 0.0, math.pi), 0.105, 0.22, path=np.array([[0.0, 0.0], [-1.5, 0.3]])
    )
    decision = ReservationTraffic().decide(0.0, [stands, closer]).decisions["closer"]
    assert decision.limit is not None and decision.limit < 0.05
