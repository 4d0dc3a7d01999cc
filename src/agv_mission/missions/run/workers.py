"""Worker processes for front doors that run many missions (regress, the service).

They fork from one fork server that has imported the mission stack already, so a worker
starts in milliseconds instead of paying the imports (MuJoCo, casadi, matplotlib) again.
"""

from __future__ import annotations

import multiprocessing
from typing import Any

#: What every worker imports before it forks: loading, running and writing a mission.
STACK_MODULES = (
    "agv_mission.missions.load.loader",
    "agv_mission.missions.run.runner",
    "agv_mission.missions.report.outputs",
    "matplotlib.pyplot",
)


def forkserver_context(entry_module: str) -> Any:
    """A forkserver context whose server preloads ``entry_module`` (where the worker
    function lives) and the mission stack."""
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([entry_module, *STACK_MODULES])
    return ctx
