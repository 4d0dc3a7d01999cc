"""One colour per robot, everywhere a robot is drawn: run.png, the dashboard and the
VDA 5050 watch page all read :data:`ROBOT_COLOURS` (a module of its own, so a page server
imports no simulator to know a colour)."""

from __future__ import annotations

#: The robots' colours, in robot order: run.png's, the dashboard's (the live stream's
#: ``robots`` message) and the VDA 5050 watch page's (its vehicles in serial order) come
#: from here alone. Matplotlib's tab10 (tab:blue, tab:red, ...), each readable on run.png's
#: white and on the dashboard's dark map.
ROBOT_COLOURS = (
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#8c564b",
    "#e377c2", "#bcbd22", "#17becf", "#7f7f7f", "#ff7f0e",
)  # fmt: skip


def robot_colour(index: int) -> str:
    """The ``index``-th robot's colour as ``#rrggbb`` (the palette repeats after ten)."""
    return ROBOT_COLOURS[index % len(ROBOT_COLOURS)]
