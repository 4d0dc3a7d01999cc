"""Dispatchers on the warehouse with real cost_grid travel times: quickest_finish picks
the robot that would be done first counting its held work; nearest_idle the nearest idle
robot; both refuse a task no robot can do."""

from __future__ import annotations

import math
from functools import cache

import pytest

from agv_mission.fleet.base import DispatchError, FleetTask, RobotWork
from agv_mission.fleet.dispatch import NearestIdleDispatcher, QuickestFinishDispatcher
from agv_mission.geometry import Pose2D as P
from agv_mission.maps.builtin_worlds import warehouse
from agv_mission.maps.costmap import Costmap, CostmapConfig
from agv_mission.planners.base import PlanningError
from agv_mission.planners.cost_grid import CostGridPlanner

SPEED = 0.22  # m/s, a burger's top speed
RADIUS = 0.105


@cache
def _costmap() -> Costmap:
    return Costmap.from_grid(warehouse().map, RADIUS, CostmapConfig())


def travel(name: str, a: P, b: P) -> float:
    """Seconds along the cost_grid plan at top speed (inf where there is none)."""
    try:
        return CostGridPlanner.shortest(0.05).plan(_costmap(), a, b).length / SPEED
    except PlanningError:
        return math.inf


IN_AISLE = P(1.8, 10.0)  # the aisle between the racks at x = 0 and x = 3.6
NEXT_AISLE = P(-1.8, 10.0)  # 3.6 m away as the crow flies, behind a 16 m rack
CROSS_AISLE = P(1.8, -0.5)  # 10.5 m away, straight down the aisle


def test_quickest_finish_counts_travel_on_the_map_not_the_crow_flies() -> None:
    robots = [RobotWork("behind_rack", NEXT_AISLE), RobotWork("down_aisle", CROSS_AISLE)]
    got = QuickestFinishDispatcher().assign(FleetTask("t", (IN_AISLE,)), robots, travel)
    assert got.robot == "down_aisle"
    assert got.bids["behind_rack"] > 1.5 * got.bids["down_aisle"]
    assert got.finish == pytest.approx(10.5 / SPEED, rel=0.05)


def test_quickest_finish_counts_the_work_a_robot_holds() -> None:
    near_busy = RobotWork("near_busy", CROSS_AISLE, held_time=20.0)
    far_idle = RobotWork("far_idle", P(-13.0, -22.0))
    task = FleetTask("t", (IN_AISLE,))
    quick = QuickestFinishDispatcher().assign(task, [far_idle, near_busy], travel)
    assert quick.robot == "near_busy"  # 20 s of work + 48 s beats 150 s of travel
    assert quick.finish == pytest.approx(20.0 + travel("", CROSS_AISLE, IN_AISLE))
    nearest = NearestIdleDispatcher().assign(task, [far_idle, near_busy], travel)
    assert nearest.robot == "far_idle"  # the only idle one
    busier = RobotWork("near_busy", CROSS_AISLE, held_time=400.0)
    assert QuickestFinishDispatcher().assign(task, [far_idle, busier], travel).robot == ("far_idle")


def test_quickest_finish_travels_through_every_goal_from_where_the_held_work_ends() -> None:
    """The bid is from the end of the robot's queue, through the goals in order."""
    task = FleetTask("t", (P(-13.0, 10.0), P(13.0, 10.0)), work_time=5.0)
    west = RobotWork("west", P(-13.0, 0.0))
    east = RobotWork("east", P(13.0, 0.0))
    got = QuickestFinishDispatcher().assign(task, [east, west], travel)
    assert got.robot == "west"  # it starts near the first goal
    through = travel("", P(-13.0, 10.0), P(13.0, 10.0))
    assert got.finish == pytest.approx(travel("", west.end, task.goals[0]) + through + 5.0)


def test_a_queue_of_tasks_spreads_over_the_fleet() -> None:
    """Released one after another (the winner's queue grows by each task), tasks in two
    aisles go one to each robot; tasks next to each other chain on one robot."""
    dispatcher = QuickestFinishDispatcher()
    robots = {"a": RobotWork("a", P(1.8, 0.0)), "b": RobotWork("b", P(5.4, 0.0))}
    goals = [P(1.8, 15.0), P(5.4, 15.0), P(5.4, 13.0), P(1.8, 13.0)]
    winners = []
    for k, goal in enumerate(goals):
        got = dispatcher.assign(FleetTask(f"t{k}", (goal,)), list(robots.values()), travel)
        winners.append(got.robot)
        robots[got.robot] = RobotWork(got.robot, goal, held_time=got.finish)
    assert winners == ["a", "b", "b", "a"]


def test_ties_go_to_the_robot_listed_first_and_answers_repeat() -> None:
    task = FleetTask("t", (P(1.8, -10.0),))  # in an aisle, 2 m from each twin
    twins = [RobotWork("left", P(1.8, -12.0)), RobotWork("right", P(1.8, -8.0))]
    for dispatcher in (QuickestFinishDispatcher(), NearestIdleDispatcher()):
        assert dispatcher.assign(task, twins, travel).robot == "left"
        assert dispatcher.assign(task, twins[::-1], travel).robot == "right"


def test_unavailable_and_unreachable_robots_are_never_picked() -> None:
    task = FleetTask("t", (IN_AISLE,))
    inside_rack = RobotWork("walled_in", P(0.0, 10.0))  # in the rack: no plan from there
    out = RobotWork("out", CROSS_AISLE, available=False)
    far = RobotWork("far", P(13.0, -22.0))
    for dispatcher in (QuickestFinishDispatcher(), NearestIdleDispatcher()):
        assert dispatcher.assign(task, [inside_rack, out, far], travel).robot == "far"
        with pytest.raises(DispatchError, match="no available robot can reach"):
            dispatcher.assign(task, [inside_rack, out], travel)
        with pytest.raises(DispatchError, match="no robots"):
            dispatcher.assign(task, [], travel)
