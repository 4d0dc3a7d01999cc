"""The run: a resolved mission in simulation, on the simulation clock.

Owns the loop over the world's robots (:func:`run_mission`, ``MissionRun``), each
robot's sense/estimate/decide/act (``RobotRun`` on its ``RobotStack``), the robot
processes a fleet may decide in (``RobotTeam``), the fleet layer's orders, a
``map_area`` task's SLAM session, the crowd, faults, what a run measured of itself, and
the hooks every front door uses (:class:`RunObserver`, :class:`RunControl`,
``StepSample``). It ends in a :class:`RunRecord`.

The names below load on first use (the loop imports MuJoCo and casadi).
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_EXPORTS = {
    "run_mission": "runner",
    "RunStopped": "errors",
    "RunObserver": "observe",
    "RunControl": "observe",
    "RunStart": "observe",
    "StepSample": "samples",
    "RunRecord": "record",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{module}"), name)
