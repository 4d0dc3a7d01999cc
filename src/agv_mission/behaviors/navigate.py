"""Navigate to a pose: the leaf every goal-directed task is made of."""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from agv_mission.geometry import Pose2D
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus


class NavigateToPose(py_trees.behaviour.Behaviour):
    """Plan to ``goal`` when first ticked, then follow until reached or given up.

    RUNNING while the navigator drives, SUCCESS at the goal (position and yaw within
    tolerance), FAILURE with the navigator's reason in ``feedback_message``.
    """

    def __init__(self, name: str, handle: RobotHandle, goal: Pose2D, **log_details: object):
        super().__init__(name)
        self.handle = handle
        self.goal = goal
        self.log_details = log_details

    def initialise(self) -> None:
        self.feedback_message = ""
        self.handle.navigator.start(self.goal, self.handle.state)

    def update(self) -> Status:
        nav = self.handle.navigator
        cmd = nav.update(self.handle.state)
        self.handle.drive(cmd.v, cmd.w)
        if nav.status is NavStatus.SUCCEEDED:
            self.handle.stop()
            est = self.handle.state.estimate
            self.handle.log(
                "goal_reached",
                goal=self.name,
                x=round(est.x, 4),
                y=round(est.y, 4),
                yaw=round(est.yaw, 4),
                **self.log_details,
            )
            return Status.SUCCESS
        if nav.status is NavStatus.FAILED:
            self.handle.stop()
            self.feedback_message = nav.reason or "navigation failed"
            return Status.FAILURE
        return Status.RUNNING

    def terminate(self, new_status: Status) -> None:
        # Halted while driving: give up the goal, unless another node has already taken the
        # navigator (a reactive parent halts this one after the higher-priority child started).
        nav = self.handle.navigator
        if new_status is Status.INVALID and self.status is Status.RUNNING and nav.goal is self.goal:
            nav.cancel()
