"""A patrol's rounds: one subtree, run ``loops`` times, so a long patrol costs one round."""

from __future__ import annotations

import py_trees
from py_trees.common import Status


class PatrolLoops(py_trees.decorators.Repeat):
    """Runs its child (one round of the waypoints) ``loops`` times, one after another.

    The round is built once and reused: ``loops: 1000000`` holds as many nodes as
    ``loops: 1``, and the simulation's time limit ends a patrol that is still going. Every
    node of the round whose ``log_details`` carry a ``loop`` gets the current round's
    number, so events and results still say which round a waypoint belonged to.
    """

    def __init__(self, name: str, child: py_trees.behaviour.Behaviour, loops: int) -> None:
        super().__init__(name=name, child=child, num_success=loops)
        self.base_name = name
        self._start_loop(1)

    @property
    def loop(self) -> int:
        """The round running now (1-based)."""
        return min(self.success + 1, self.num_success)

    def initialise(self) -> None:
        super().initialise()
        self._start_loop(1)

    def update(self) -> Status:
        status = super().update()
        if status is Status.RUNNING and self.decorated.status is Status.SUCCESS:
            self._start_loop(self.success + 1)
        return status

    def _start_loop(self, loop: int) -> None:
        self.name = f"{self.base_name} (loop {loop}/{self.num_success})"
        for node in self.decorated.iterate():
            details = getattr(node, "log_details", None)
            if isinstance(details, dict) and "loop" in details:
                details["loop"] = loop
