"""Nav2's decorators, and its two navigators: ``navigate_to_pose`` /
``navigate_through_poses`` running a navigator tree (Nav2's NavigateToPose and
NavigateThroughPoses actions with their ``behavior_tree``), and
``navigate_through_poses`` without one (a leg per goal, with our recoveries)."""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

import py_trees
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.decorators import _Gate, _Throttle
from agv_mission.behaviors.nav2 import NavPath, arc_lengths, arc_position
from agv_mission.geometry import Pose2D
from agv_mission.navigation.handle import RobotHandle

Behaviour = py_trees.behaviour.Behaviour


class DistanceController(_Throttle):
    """Ticks its child at the start and after every ``distance`` metres driven."""

    def __init__(
        self, name: str, child: Behaviour, handle: RobotHandle, distance: float = 1.0, **_: Any
    ):
        super().__init__(name, child, handle)
        self.distance = distance
        self._from: Pose2D | None = None

    def reset(self) -> None:
        self._from = None

    def due(self) -> bool:
        return self._from is None or (
            self.handle.state.estimate.distance_to(self._from) >= self.distance
        )

    def ticked(self, status: Status) -> None:
        self._from = self.handle.state.estimate


class SpeedController(_Throttle):
    """Ticks its child at a rate from ``min_rate`` (at ``min_speed``) to ``max_rate``
    (at ``max_speed``), by the robot's commanded speed."""

    def __init__(
        self, name: str, child: Behaviour, handle: RobotHandle, min_rate: float = 0.1,
        max_rate: float = 1.0, min_speed: float = 0.0, max_speed: float = 0.5, **_: Any,
    ):  # fmt: skip
        super().__init__(name, child, handle)
        self.rates = (min_rate, max_rate)
        self.speeds = (min_speed, max(max_speed, min_speed + 1e-6))
        self._next = -math.inf

    def reset(self) -> None:
        self._next = -math.inf

    def due(self) -> bool:
        return self.handle.state.time >= self._next - 1e-9

    def ticked(self, status: Status) -> None:
        speed = abs(self.handle.state.velocity[0])
        lo, hi = self.speeds
        share = min(max((speed - lo) / (hi - lo), 0.0), 1.0)
        rate = self.rates[0] + share * (self.rates[1] - self.rates[0])
        self._next = self.handle.state.time + 1.0 / rate


class GoalUpdatedController(_Throttle):
    """Ticks its child at the start and whenever the goal (or goals) changes."""

    def __init__(
        self, name: str, child: Behaviour, handle: RobotHandle, context: TreeContext,
        goal: str = "goal", goals: str = "goals",
    ):  # fmt: skip
        super().__init__(name, child, handle)
        self.context, self.keys = context, (goal, goals)
        self._seen: Any = None

    def _now(self) -> Any:
        bb = self.context.blackboard
        goals = bb.get(self.keys[1])
        return (bb.get(self.keys[0]), tuple(goals) if goals is not None else None)

    def reset(self) -> None:
        self._seen = None

    def due(self) -> bool:
        return self._now() != self._seen

    def ticked(self, status: Status) -> None:
        self._seen = self._now()


class GoalUpdater(py_trees.decorators.Decorator):
    """Copies the goal (goals) to its output entry, then ticks its child: no goal topic
    updates it here."""

    def __init__(
        self, name: str, child: Behaviour, context: TreeContext, input_goal: str | None = None,
        output_goal: str | None = None, input_goals: str | None = None,
        output_goals: str | None = None,
    ):  # fmt: skip
        super().__init__(name=name, child=child)
        self.context = context
        self.copies = [(input_goal, output_goal), (input_goals, output_goals)]

    def tick(self) -> Iterator[Behaviour]:
        bb = self.context.blackboard
        for source, target in self.copies:
            if source and target and source in bb:
                bb[target] = bb[source]
        yield from super().tick()

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return self.decorated.status


class PathLongerOnApproach(_Gate):
    """Ticks its child when a new path, within ``prox_len`` of the goal, is more than
    ``length_factor`` times as long as the one before; otherwise succeeds."""

    def __init__(
        self, name: str, child: Behaviour, handle: RobotHandle, context: TreeContext, path: str,
        prox_len: float = 3.0, length_factor: float = 2.0,
    ):  # fmt: skip
        super().__init__(name=name, child=child)
        self.handle, self.context, self.key = handle, context, path
        self.prox_len, self.factor = prox_len, length_factor
        self._old: NavPath | None = None

    def gate(self) -> Status | None:
        if self.decorated.status is Status.RUNNING:
            return None
        path = self.context.blackboard.get(self.key)
        old, self._old = self._old, path if isinstance(path, NavPath) else self._old
        if not isinstance(path, NavPath) or old is None or path is old:
            return Status.SUCCESS
        left = float(arc_lengths(old.points)[-1]) - arc_position(
            old.points, self.handle.state.estimate
        )
        longer = float(arc_lengths(path.points)[-1]) > self.factor * max(left, 1e-6)
        if left <= self.prox_len and longer and path.goal == old.goal:
            self.handle.log("path_longer_on_approach", node=self.name)
            return None
        return Status.SUCCESS


class SingleTrigger(_Gate):
    """Ticks its child until it has ended once; fails from then on."""

    def __init__(self, name: str, child: Behaviour):
        super().__init__(name=name, child=child)
        self._done = False

    def gate(self) -> Status | None:
        return Status.FAILURE if self._done else None

    def update(self) -> Status:
        status = self.decorated.status
        if status is not Status.RUNNING:
            self._done = True
        return status


class BtNavigator(py_trees.decorators.Decorator):
    """Nav2's NavigateToPose / NavigateThroughPoses action with a ``behavior_tree``: each
    time it starts, the tree's blackboard (its own entries, ``prefix.*``) is cleared and
    ``goal`` (or ``goals``) written to it; then the tree runs. Its status is the tree's."""

    def __init__(self, name: str, child: Behaviour, context: TreeContext, node: Any, prefix: str):
        """``node``: the validated navigator node (``missions.load.tree_spec.Node``)."""
        super().__init__(name=name, child=child)
        self.context, self.node, self.prefix = context, node, prefix
        self.handle = context.handle
        self.through = node.type == "navigate_through_poses"

    def initialise(self) -> None:
        self.feedback_message = ""
        bb = self.context.blackboard
        for key in [k for k in bb if k.startswith(f"{self.prefix}.")]:
            del bb[key]
        values = dict(self.node.literal)
        if self.node.ports is not None:
            values = {k: getattr(self.node.ports, k) for k in ("goal", "goals") if k in values}
        for port, key in self.node.bound.items():
            values[port] = bb.get(key)
        try:
            if self.through:
                goals = [self.context.goal_pose(g) for g in values.get("goals") or []]
                bb[f"{self.prefix}.goals"] = goals
                target = goals[-1] if goals else None
            else:
                target = self.context.goal_pose(values.get("goal"))
                bb[f"{self.prefix}.goal"] = target
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            self.feedback_message = f"bad goal: {exc}"
            target = None
        self._target = target
        if target is not None:
            self.handle.log(
                "navigate", node=self.name, tree=self.node.tree_id or "",
                x=round(target.x, 4), y=round(target.y, 4), yaw=round(target.yaw, 4),
            )  # fmt: skip

    def tick(self) -> Iterator[Behaviour]:
        if self.status is not Status.RUNNING:
            self.initialise()
        if self._target is None:
            self.stop(Status.FAILURE)
            self.status = Status.FAILURE
            yield self
            return
        yield from self.decorated.tick()
        status = self.update()
        if status is not Status.RUNNING:
            self.stop(status)
        self.status = status
        yield self

    def update(self) -> Status:
        status = self.decorated.status
        if status is Status.SUCCESS:
            self.handle.stop()
            est = self.handle.state.estimate
            self.handle.log("goal_reached", goal=self.name, x=round(est.x, 4),
                            y=round(est.y, 4), yaw=round(est.yaw, 4))  # fmt: skip
        elif status is Status.FAILURE:
            self.handle.stop()
            self.feedback_message = _why(self.decorated) or "the navigator tree failed"
        return status

    def terminate(self, new_status: Status) -> None:
        nav = self.handle.navigator
        if new_status is Status.INVALID and self.status is Status.RUNNING and nav.external:
            nav.cancel()


def _why(root: Behaviour) -> str:
    """The last failed node's message in ``root``'s subtree (pre-order)."""
    message = ""
    for node in root.iterate():
        if node.status is Status.FAILURE and node.feedback_message:
            message = node.feedback_message
    return message


class NavigateThroughGoals(py_trees.decorators.Decorator):
    """Drive through the goals in order, each a leg with our recoveries (without a
    ``behavior_tree``)."""

    def __init__(
        self, name: str, handle: RobotHandle, goals: list[Any], context: TreeContext,
        behavior_tree: str | None = None, **_ros: Any,
    ):  # fmt: skip
        from agv_mission.behaviors.tasks import goal_leg

        legs = []
        for i, goal in enumerate(goals):
            p = context.goal_pose(goal)
            legs.append(goal_leg(f"goal {i + 1} ({p.x:g}, {p.y:g})", p, context))
        seq = py_trees.composites.Sequence(name="goals", memory=True, children=legs)
        super().__init__(name=name, child=seq)

    def update(self) -> Status:
        if self.decorated.status is Status.FAILURE:
            self.feedback_message = self.decorated.feedback_message
        return self.decorated.status


from agv_mission.behaviors.ports import nav2_flow as _p  # noqa: E402

# The ports of each node type this module's behaviours are (registry slot `behavior`).
DistanceController.Config = _p.DistanceControllerPorts
SpeedController.Config = _p.SpeedControllerPorts
GoalUpdatedController.Config = _p.GoalUpdatedControllerPorts
GoalUpdater.Config = _p.GoalUpdaterPorts
PathLongerOnApproach.Config = _p.PathLongerOnApproachPorts
SingleTrigger.Config = _p.SingleTriggerPorts
NavigateThroughGoals.Config = _p.NavigateThroughPosesPorts
