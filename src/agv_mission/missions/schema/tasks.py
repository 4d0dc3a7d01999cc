"""The ``tasks`` of a mission: what the robot does, one discriminated union by ``type``.

Each task type is an action node of the tree library; its model (its ports) lives with
the node library in :mod:`agv_mission.behaviors.ports`.
"""

from agv_mission.behaviors.ports import (
    AreaBounds,
    ChargeTask,
    DockTask,
    FailurePolicy,
    GoToTask,
    MapAreaTask,
    PatrolTask,
    RecordRoomTask,
    SettleBeforeRecording,
    Task,
    TeleopTask,
    UndockTask,
    VisitRoomsTask,
    WanderTask,
)

__all__ = [
    "AreaBounds",
    "ChargeTask",
    "DockTask",
    "FailurePolicy",
    "GoToTask",
    "MapAreaTask",
    "PatrolTask",
    "RecordRoomTask",
    "SettleBeforeRecording",
    "Task",
    "TeleopTask",
    "UndockTask",
    "VisitRoomsTask",
    "WanderTask",
]
