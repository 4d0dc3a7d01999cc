"""SIGINT and SIGTERM for a run started from a terminal: stop while loading, cancel once
running (a :class:`~agv_mission.missions.run.observe.RunControl`), and the exit code they mean."""

from __future__ import annotations

import signal
from typing import Any

from agv_mission.missions.run.errors import RunStopped

SIGNAL_EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


class SignalStop:
    """While the mission loads a signal stops it at once; once it runs a signal only asks,
    and :meth:`before_step` ends the run ``aborted`` before the next step. (Raising inside
    the loop is not enough: casadi, for one, catches the KeyboardInterrupt a solve is
    interrupted with, prints it and goes on.)"""

    only_cancels = True  # robots may decide in other processes (missions.run.team)

    def __init__(self) -> None:
        self.phase = "loading"  # then "running" (once the run has ended, nothing to stop)
        self.received: list[int] = []

    def install(self) -> SignalStop:
        """Handle SIGINT and SIGTERM from now on."""
        for sig in SIGNAL_EXIT_CODES:
            signal.signal(sig, self.handle)
        return self

    def ignore(self) -> None:
        """Ignore SIGINT and SIGTERM from now on: once everything is written a signal must
        not turn the exit code into a kill (Python restores the default handlers while it
        shuts down)."""
        for sig in SIGNAL_EXIT_CODES:
            signal.signal(sig, signal.SIG_IGN)

    def handle(self, signum: int, _frame: object) -> None:
        self.received.append(signum)
        if self.phase == "loading" and len(self.received) == 1:
            if signum == signal.SIGINT:
                raise KeyboardInterrupt
            raise RunStopped(f"stopped by {signal.Signals(signum).name}", signum)

    @property
    def exit_code(self) -> int | None:
        """130 after SIGINT, 143 after SIGTERM (the first one received), else None."""
        return SIGNAL_EXIT_CODES[self.received[0]] if self.received else None

    def before_step(self, run: Any) -> None:
        if self.received and self.phase == "running":
            first = self.received[0]
            run.cancel(
                "interrupted by the user (Ctrl-C)"
                if first == signal.SIGINT
                else f"stopped by {signal.Signals(first).name}"
            )
