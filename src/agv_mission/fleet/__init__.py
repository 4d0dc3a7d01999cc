"""The fleet layer (floor 4): which robot does a task (``dispatcher`` slot) and how robots
keep out of each other's way (``traffic`` slot). It sees robots only as the plain data of
:mod:`agv_mission.fleet.base`; the run wires it to the robots' navigators."""

from agv_mission.fleet.base import (
    Assignment,
    Dispatcher,
    DispatchError,
    FleetEvent,
    FleetTask,
    RobotWork,
    TrafficController,
    TrafficDecision,
    TrafficRobot,
    TrafficUpdate,
    TravelTime,
)

__all__ = [
    "Assignment",
    "DispatchError",
    "Dispatcher",
    "FleetEvent",
    "FleetTask",
    "RobotWork",
    "TrafficController",
    "TrafficDecision",
    "TrafficRobot",
    "TrafficUpdate",
    "TravelTime",
]
