"""Room leaves: check that the robot is in a room, and record where it is."""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from agv_mission.behaviors.motion import Dwell
from agv_mission.maps.rooms import Room
from agv_mission.navigation.handle import RobotHandle


class InRoom(py_trees.behaviour.Behaviour):
    """SUCCESS when the estimated position lies inside ``room``'s polygon."""

    def __init__(self, name: str, handle: RobotHandle, room: Room):
        super().__init__(name)
        self.handle = handle
        self.room = room

    def update(self) -> Status:
        est = self.handle.state.estimate
        if self.room.contains(est.x, est.y):
            return Status.SUCCESS
        self.feedback_message = (
            f"robot at ({est.x:.2f}, {est.y:.2f}) is not inside room {self.room.label!r}"
        )
        return Status.FAILURE


class RecordRoom(py_trees.behaviour.Behaviour):
    """Record the estimated pose under ``label`` (``rosservice call room_service label``)."""

    def __init__(self, name: str, handle: RobotHandle, label: str, **log_details: object):
        super().__init__(name)
        self.handle = handle
        self.label = label
        self.log_details = log_details

    def update(self) -> Status:
        try:
            pose = self.handle.record(self.label)
        except OSError as exc:
            self.feedback_message = f"cannot write the recorder file: {exc}"
            return Status.FAILURE
        self.handle.log_recorded(self.label, pose, **self.log_details)
        return Status.SUCCESS


class SettleLocalization(Dwell):
    """Stand still for ``duration`` simulated seconds, the localiser updating on every scan.

    Before a pose is recorded: a filter that only updates after motion keeps whatever
    spread the last turn in place gave it (amcl's ``request_nomotion_update``).
    """

    def update(self) -> Status:
        status = super().update()
        if status is Status.RUNNING:
            self.handle.nomotion_update = True
        return status
