"""The typed ports of every built-in node type, and the poses they carry.

Each node type's ports are a :class:`NodePorts` model (a plugin config of the registry's
``behavior`` slot): its fields are the ports (type, default, description), its ``type``
is the node's snake_case name, its ``plugin`` names the behaviour class, loaded only when
a tree is built, and its ``kind`` says how the assembly builds it (``action`` and
``condition``: ``cls(name, handle, **ports)``; ``decorator``: ``cls(name, child,
**ports)``; ``control``: ``cls(name, children, **ports)``). This package imports only
pydantic: validating a mission or printing the schema never loads the behaviours.

:mod:`.values` (poses, areas, blackboard references), :mod:`.node` (``NodePorts`` by
kind) and :mod:`.tasks` (the task types of ``mission-format.md``) are exported from here;
the ports of the other nodes live beside the behaviours they configure: :mod:`.controls`,
:mod:`.decorators`, :mod:`.conditions`, :mod:`.actions`, :mod:`.btcpp` (BT.CPP's
built-ins), :mod:`.nav2`, :mod:`.nav2_conditions` and :mod:`.nav2_flow` (Nav2's nodes).
"""

from agv_mission.behaviors.ports.node import (
    ConditionPorts,
    ControlPorts,
    DecoratorPorts,
    ErrorOutputs,
    NodeKind,
    NodePorts,
    RosPlumbing,
    entry_port,
    output_port,
)
from agv_mission.behaviors.ports.tasks import (
    ChargeTask,
    DockTask,
    FailurePolicy,
    GoToTask,
    MapAreaTask,
    PatrolTask,
    RecordRoomTask,
    SettleBeforeRecording,
    Task,
    TaskPorts,
    TeleopTask,
    UndockTask,
    VisitRoomsTask,
    WanderTask,
)
from agv_mission.behaviors.ports.values import (
    BLACKBOARD_REF,
    MAX_LOOPS,
    MAX_ROOMS,
    MAX_SIM_SECONDS,
    MAX_WAYPOINTS,
    QUATERNION_TOLERANCE,
    ROS_POSE_SCHEMA,
    AreaBounds,
    FieldPath,
    Goal,
    Orientation,
    Pose,
    Position,
    StrictModel,
    blackboard_key,
)

__all__ = [
    "AreaBounds",
    "BLACKBOARD_REF",
    "ChargeTask",
    "ConditionPorts",
    "ControlPorts",
    "DecoratorPorts",
    "DockTask",
    "ErrorOutputs",
    "FailurePolicy",
    "FieldPath",
    "GoToTask",
    "Goal",
    "MAX_LOOPS",
    "MAX_ROOMS",
    "MAX_SIM_SECONDS",
    "MAX_WAYPOINTS",
    "MapAreaTask",
    "NodeKind",
    "NodePorts",
    "Orientation",
    "PatrolTask",
    "Pose",
    "Position",
    "QUATERNION_TOLERANCE",
    "ROS_POSE_SCHEMA",
    "RecordRoomTask",
    "RosPlumbing",
    "SettleBeforeRecording",
    "StrictModel",
    "Task",
    "TaskPorts",
    "TeleopTask",
    "UndockTask",
    "VisitRoomsTask",
    "WanderTask",
    "blackboard_key",
    "entry_port",
    "output_port",
]
