"""Two runs' CPU compared as this machine allows: stepped side by side in one process.

This machine's speed moves within seconds (2x between states), so whole runs one after
the other compare moments, not code. Here the runs step in turn, one control step each,
and each step's thread CPU is counted to its run: both see the same moments. The run
stepped first in a round pays a little for cold caches (about 2 %), so a pairing runs in
both orders and its ratio is the geometric mean of the two.

For runs of one world only: each run evicts the other's caches, which costs a run with a
larger working set (a larger map, costmap and distance field) more than it would pay
alone (the 30 x 50 m warehouse against the demo's arena read 1.19 side by side, 0.85 in
whole runs).
"""

from __future__ import annotations

import gc
import statistics
import time
from collections.abc import Callable
from typing import Any

from agv_mission.missions.run.runner import MissionRun


def step_in_turn(runs: list[MissionRun]) -> list[float]:
    """Thread CPU seconds each run's steps took, the runs stepped in turn to their end."""
    cpu, live = [0.0] * len(runs), [True] * len(runs)
    gc.freeze()  # as MissionRun.drive: the set-up's objects out of the collector's way
    try:
        while any(live):
            for i, run in enumerate(runs):
                if live[i]:
                    start = time.thread_time()
                    live[i] = run.step()
                    cpu[i] += time.thread_time() - start
    finally:
        gc.unfreeze()
    return cpu


def paired_ratio(
    make_a: Callable[[], MissionRun],
    make_b: Callable[[], MissionRun],
    pairs: int = 3,
    check: Callable[[str, Any], None] | None = None,
) -> float:
    """The median over ``pairs`` of B's CPU per simulated second over A's, each pairing in
    both orders; ``check(kind, record)`` sees every run's record (``kind`` "a" or "b")."""
    ratios = []
    for _ in range(pairs):
        costs: dict[str, list[float]] = {"a": [], "b": []}
        for kinds in ("ab", "ba"):
            runs = [make_a() if kind == "a" else make_b() for kind in kinds]
            for kind, run, cpu in zip(kinds, runs, step_in_turn(runs), strict=True):
                record = run.record()
                if check is not None:
                    check(kind, record)
                costs[kind].append(cpu / record.sim_time)
        ratios.append(((costs["b"][0] / costs["a"][0]) * (costs["b"][1] / costs["a"][1])) ** 0.5)
    return statistics.median(ratios)
