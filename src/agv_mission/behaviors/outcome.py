"""The failure policy of one leg of a task (a waypoint, a room, a goal)."""

from __future__ import annotations

import py_trees
from py_trees.common import Status

from agv_mission.navigation.handle import RobotHandle


def failure_reason(node: py_trees.behaviour.Behaviour) -> str:
    """The feedback of the deepest failed leaf under ``node`` (why it failed)."""
    for child in node.iterate():
        if child.status is Status.FAILURE and not child.children and child.feedback_message:
            return child.feedback_message
    return node.feedback_message or "failed"


class LegOutcome(py_trees.decorators.Decorator):
    """Logs how a leg ended and applies ``on_failure: skip`` (a failed leg lets the task go on).

    The log (``goal_failed`` / ``goal_skipped`` with the reason) is what ``result.json``
    reports per waypoint and per room.
    """

    def __init__(
        self,
        name: str,
        child: py_trees.behaviour.Behaviour,
        handle: RobotHandle,
        skip: bool,
        **log_details: object,
    ):
        super().__init__(name=name, child=child)
        self.handle = handle
        self.skip = skip
        self.log_details = log_details

    def update(self) -> Status:
        status = self.decorated.status
        if status is not Status.FAILURE:
            return status
        self.feedback_message = failure_reason(self.decorated)
        event = "goal_skipped" if self.skip else "goal_failed"
        self.handle.log(event, reason=self.feedback_message, **self.log_details)
        return Status.SUCCESS if self.skip else Status.FAILURE
