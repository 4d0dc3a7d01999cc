"""Watchable runs: simulated time held to a pace a person can follow.

A pace is simulated seconds per wall second (``--pace 1.0``: real time; absent: as fast
as the run goes). Pacing only waits between control steps, on the wall clock: the steps
themselves, and so the run's results, are those of the same seed run flat out.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

#: The paces a run keeps (simulated seconds per wall second): a thousandth of real time
#: (a second of the run in 17 minutes) to a million times it (beyond, a step of the slowest
#: runs already takes longer than the pace leaves it). Outside, a wait overflows the clock.
PACE_RANGE = (1e-3, 1e6)
#: wall seconds a paced run may fall behind its pace before it stops catching up (a slow
#: stretch, a pause) and keeps the pace from where it is
CATCH_UP = 0.5


def check_pace(pace: float | None) -> float | None:
    """``pace`` when it is a number of simulated seconds per wall second in
    :data:`PACE_RANGE` (None: as fast as it goes); ValueError otherwise."""
    if pace is None:
        return None
    if isinstance(pace, bool) or not isinstance(pace, int | float):
        raise ValueError("pace is a number: simulated seconds per wall second")
    lo, hi = PACE_RANGE
    if not lo <= pace <= hi:  # nan too
        raise ValueError(f"pace is a number of simulated seconds per wall second in {lo:g}..{hi:g}")
    return float(pace)


class Pacer:
    """Keeps simulated time from running ahead of ``pace`` times the wall clock.

    :meth:`delay` says how long to wait before the next step; the caller waits its own
    way (a plain sleep, or a wait that answers commands meanwhile)."""

    def __init__(self, pace: float | None = None) -> None:
        self.pace = check_pace(pace)
        self._origin: tuple[float, float, float] | None = None  # (wall, sim, pace) counted from

    def set(self, pace: float | None) -> None:
        """A new pace, counted from the next step."""
        self.pace = check_pace(pace)
        self._origin = None

    def restart(self) -> None:
        """Count the pace afresh from the next step (after a pause)."""
        self._origin = None

    def delay(self, sim_time: float, pace: float | None = None) -> float:
        """Wall seconds to wait before the step at ``sim_time`` (0: go now) at ``pace``
        (default: this pacer's)."""
        pace = self.pace if pace is None else pace
        if pace is None:
            self._origin = None
            return 0.0
        now = time.monotonic()
        if self._origin is None or self._origin[2] != pace:
            self._origin = (now, sim_time, pace)
            return 0.0
        wall0, sim0, _ = self._origin
        wait = (sim_time - sim0) / pace - (now - wall0)
        if wait < -CATCH_UP or wait > CATCH_UP + 1.0 / pace:  # fell behind, or a time jump
            self._origin = (now, sim_time, pace)
            return 0.0
        return max(wait, 0.0)


class PacedControl:
    """A run control that paces the run and passes every step on to ``inner`` (the
    command line's signal handler): it never commands a robot, so a fleet's robots may
    still decide in processes of their own."""

    only_cancels = True

    def __init__(
        self, inner: Any, pace: float, sleep: Callable[[float], None] = time.sleep
    ) -> None:
        self.inner = inner
        self.pacer = Pacer(pace)
        self.sleep = sleep

    def before_step(self, run: Any) -> None:
        wait = self.pacer.delay(run.world.time)
        if wait > 0:
            self.sleep(wait)
        if self.inner is not None:
            self.inner.before_step(run)
