"""What people cost a run (issue 25): one burger patrolling the built-in 30 x 50 m warehouse
with 0, 10 and 50 people wandering it, everything a ``agv-mission run`` does included (the
crowd, their bodies in the physics and the lidar's rays, the bag's ``/people``,
``people.csv``). Thread CPU time per simulated second, the three runs interleaved and
repeated, medians of the per-round ratios to the run without people (a CPU speed change
between rounds cancels out). The crowd's own step is timed apart.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from agv_mission.bags.writer import BagWriter
from agv_mission.maps.builtin_worlds import warehouse
from agv_mission.missions.loader import load_mission
from agv_mission.missions.outputs import write_run
from agv_mission.missions.runner import MissionRun
from agv_mission.world.crowd import Crowd, PeopleGroup

ROUNDS = 3
SIM_SECONDS = 60.0
COUNTS = (0, 10, 50)
WHOLE = "[[-14.9, -24.9], [14.9, -24.9], [14.9, 24.9], [-14.9, 24.9]]"
MISSION = """
name: people-bench
world: warehouse
robot: burger
start: {{x: 0.0, y: -22.0, yaw: 1.5708}}
seed: 5
stack:
  localization: {{type: ground_truth}}
{people}
tasks:
  - type: patrol
    loops: 20
    waypoints:
      - {{x: -1.8, y: -6.0, yaw: 1.5708}}
      - {{x: -1.8, y: -16.0, yaw: -1.5708}}
limits: {{time: {limit}}}
"""


def _mission(tmp: Path, count: int) -> Path:
    people = f"people:\n  - {{count: {count}, area: {WHOLE}}}" if count else ""
    path = tmp / f"people_{count}.yaml"
    path.write_text(MISSION.format(people=people, limit=SIM_SECONDS))
    return path


def _cpu_per_sim_s(path: Path, out: Path) -> float:
    """Thread CPU seconds per simulated second of one run, bag and run directory included."""
    loaded = load_mission(path)
    run_dir = out / f"{path.stem}_{len(list(out.iterdir()))}"
    run_dir.mkdir()
    writer = BagWriter(run_dir / "bag").prepare()
    t0 = time.thread_time()
    run = MissionRun(loaded, run_dir, [writer])
    run.notify_start()
    run.drive()
    record = run.record()
    writer.on_end(record)
    write_run(run_dir, loaded, record)
    return (time.thread_time() - t0) / max(run.world.time, 1e-9)


def _crowd_ms_per_sim_s(count: int) -> float:
    """The crowd's own step (ORCA and routing) for ``count`` people, per simulated second."""
    area = ((-14.9, -24.9), (14.9, -24.9), (14.9, 24.9), (-14.9, 24.9))
    crowd = Crowd(
        [PeopleGroup(count=count, behaviour="wander", area=area)],
        warehouse().map,
        np.random.default_rng(1),
    )
    robots = np.array([[0.0, -21.0, 0.2, 0.0, 0.105]])
    for _ in range(20):
        crowd.step(0.1, robots)
    steps = 600
    t0 = time.thread_time()
    for _ in range(steps):
        crowd.step(0.1, robots)
    return (time.thread_time() - t0) / (steps * 0.1) * 1e3


def run() -> dict[str, float]:
    costs: dict[int, list[float]] = {n: [] for n in COUNTS}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        paths = {n: _mission(tmp_path, n) for n in COUNTS}
        _cpu_per_sim_s(paths[0], tmp_path)  # warm the caches (casadi, typestore) first
        for _ in range(ROUNDS):
            for n in COUNTS:
                costs[n].append(_cpu_per_sim_s(paths[n], tmp_path))
    results: dict[str, float] = {}
    for n in COUNTS:
        results[f"people.n{n}.cpu_ms_per_sim_s"] = round(statistics.median(costs[n]) * 1e3, 3)
        if n:
            ratios = [a / b for a, b in zip(costs[n], costs[0], strict=True)]
            results[f"people.n{n}.cost_ratio"] = round(statistics.median(ratios), 4)
            results[f"people.n{n}.crowd_ms_per_sim_s"] = round(_crowd_ms_per_sim_s(n), 3)
    return results
