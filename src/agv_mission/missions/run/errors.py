"""How a run is stopped from outside."""

from __future__ import annotations


class RunStopped(BaseException):
    """Raised (by a signal handler of the front door) to stop a run from outside, e.g. on
    SIGTERM. Not an ``Exception``: no ``except Exception`` on the way swallows it."""

    def __init__(self, reason: str, signum: int | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.signum = signum
