"""The teleop task's leaf: the robot under remote command, with an optional goal drive."""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus


class RemoteControl(py_trees.behaviour.Behaviour):
    """Drive ``handle.remote_command`` (stop when it is None: the front door clears it when
    commands stop coming). A ``handle.remote_goal`` is navigated to first, then remote
    command resumes. Succeeds after ``duration`` simulated seconds; runs on otherwise."""

    def __init__(
        self, name: str, handle: RobotHandle, duration: float | None, **log_details: object
    ):
        super().__init__(name)
        self.handle = handle
        self.duration = duration
        self.log_details = log_details
        self._until: float | None = None
        self._goal_active = False

    def initialise(self) -> None:
        now = self.handle.state.time
        self._until = None if self.duration is None else now + self.duration
        self._goal_active = False
        self.handle.remote_goal = None
        self.feedback_message = "remote command"

    def update(self) -> Status:
        handle = self.handle
        if self._until is not None and handle.state.time >= self._until - 1e-9:
            self._cancel_goal()
            handle.stop()
            return Status.SUCCESS
        if handle.remote_goal is not None:
            self._drive_to_goal()
            return Status.RUNNING
        command = handle.remote_command
        if command is None:
            handle.stop()
            self.feedback_message = "waiting for commands"
        else:
            handle.drive(*command)
            self.feedback_message = "remote command"
        return Status.RUNNING

    def _drive_to_goal(self) -> None:
        handle, nav = self.handle, self.handle.navigator
        goal = handle.remote_goal
        assert goal is not None
        if not self._goal_active or nav.goal is None or nav.goal != goal:
            nav.start(goal, handle.state, *handle.remote_goal_tolerance)
            self._goal_active = True
            handle.log(
                "goal_sent",
                x=round(goal.x, 4),
                y=round(goal.y, 4),
                yaw=round(goal.yaw, 4),
                **self.log_details,
            )
        cmd = nav.update(handle.state)
        cap = handle.remote_speed_limit
        handle.drive(cmd.v if cap is None else max(-cap, min(cap, cmd.v)), cmd.w)
        self.feedback_message = f"to goal ({goal.x:.2f}, {goal.y:.2f})"
        if nav.status is NavStatus.SUCCEEDED or nav.status is NavStatus.FAILED:
            est = handle.state.estimate
            if nav.status is NavStatus.SUCCEEDED:
                handle.log(
                    "goal_reached",
                    goal="remote goal",
                    x=round(est.x, 4),
                    y=round(est.y, 4),
                    yaw=round(est.yaw, 4),
                    **self.log_details,
                )
            else:
                handle.log(
                    "goal_failed",
                    goal="remote goal",
                    reason=nav.reason or "navigation failed",
                    **self.log_details,
                )
            handle.stop()
            handle.remote_goal = None
            self._goal_active = False
            nav.cancel()

    def _cancel_goal(self) -> None:
        if self._goal_active:
            self.handle.navigator.cancel()
            self._goal_active = False
        self.handle.remote_goal = None

    def terminate(self, new_status: Status) -> None:
        if new_status is Status.INVALID:
            self._cancel_goal()
