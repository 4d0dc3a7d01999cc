"""What people cost a run (issue 25): one burger patrolling the built-in 30 x 50 m warehouse
with 0, 10 and 50 people wandering it, with the default stack (amcl and the MPC: what a
user's run costs) and with a perfect localiser (``ground_truth``: the robot's own software
cheaper, so people's share larger), everything a ``agv-mission run`` does included (the
crowd, their bodies in the physics and the lidar's rays, the bag's ``/people``,
``people.csv``) over 120 simulated seconds. Thread CPU time per simulated second, the six
runs interleaved, three rounds of a seed each (who meets the robot where, and so what they
cost it, varies with the seed), medians of the per-round ratios to the run without people
with the same stack (a CPU speed change between rounds cancels out); the loop alone and the
set-up (building the crowd: the free space's outline, the routing grid, ORCA's obstacles)
apart, and the crowd's own step."""

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

SEEDS = (5, 6, 7)  # one round each
SIM_SECONDS = 120.0
COUNTS = (0, 10, 50)
WHOLE = "[[-14.9, -24.9], [14.9, -24.9], [14.9, 24.9], [-14.9, 24.9]]"
MISSION = """
name: people-bench
world: warehouse
robot: burger
start: {{x: 0.0, y: -22.0, yaw: 1.5708}}
seed: {seed}
{stack}{people}
tasks:
  - type: patrol
    loops: 20
    waypoints:
      - {{x: -1.8, y: -6.0, yaw: 1.5708}}
      - {{x: -1.8, y: -16.0, yaw: -1.5708}}
limits: {{time: {limit}}}
"""


# the stack a one-robot run gets by default (amcl, the MPC: mission-format.md), and the same
# with a perfect localiser (what the robot's software alone costs drops, people's share rises)
STACKS = {"default": "", "ground_truth": "stack:\n  localization: {type: ground_truth}\n"}


def _mission(tmp: Path, count: int, stack: str = "default", seed: int = 5) -> Path:
    people = f"people:\n  - {{count: {count}, area: {WHOLE}}}" if count else ""
    path = tmp / f"people_{stack}_{count}_{seed}.yaml"
    text = MISSION.format(stack=STACKS[stack], people=people, limit=SIM_SECONDS, seed=seed)
    path.write_text(text)
    return path


def _cpu_per_sim_s(path: Path, out: Path) -> tuple[float, float, float]:
    """Thread CPU seconds per simulated second of one run, bag and run directory included;
    of its loop alone; and the seconds its set-up took."""
    loaded = load_mission(path)
    run_dir = out / f"{path.stem}_{len(list(out.iterdir()))}"
    run_dir.mkdir()
    writer = BagWriter(run_dir / "bag").prepare()
    t0 = time.thread_time()
    run = MissionRun(loaded, run_dir, [writer])
    t1 = time.thread_time()
    run.notify_start()
    run.drive()
    t2 = time.thread_time()
    record = run.record()
    writer.on_end(record)
    write_run(run_dir, loaded, record)
    sim = max(run.world.time, 1e-9)
    return (time.thread_time() - t0) / sim, (t2 - t1) / sim, t1 - t0


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
    """``people.nN.*``: the default stack's runs (amcl and the MPC, what a user's run
    costs); ``people.ground_truth.nN.*``: the same with a perfect localiser."""
    runs = [(stack, n) for stack in STACKS for n in COUNTS]
    whole: dict[tuple[str, int], list[float]] = {k: [] for k in runs}
    loop: dict[tuple[str, int], list[float]] = {k: [] for k in runs}
    setup: dict[tuple[str, int], list[float]] = {k: [] for k in runs}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        for k in runs:  # warm the caches (casadi, typestore, matplotlib) first
            _cpu_per_sim_s(_mission(tmp_path, k[1], k[0]), tmp_path)
        for seed in SEEDS:  # a round per seed: who meets the robot where varies with it
            for k in runs:
                a, b, c = _cpu_per_sim_s(_mission(tmp_path, k[1], k[0], seed), tmp_path)
                whole[k].append(a)
                loop[k].append(b)
                setup[k].append(c)
    results: dict[str, float] = {}
    for stack, n in runs:
        key = f"people.n{n}" if stack == "default" else f"people.{stack}.n{n}"
        k = (stack, n)
        results[f"{key}.cpu_ms_per_sim_s"] = round(statistics.median(whole[k]) * 1e3, 3)
        results[f"{key}.loop_ms_per_sim_s"] = round(statistics.median(loop[k]) * 1e3, 3)
        results[f"{key}.setup_ms"] = round(statistics.median(setup[k]) * 1e3, 1)
        if n:
            for name, costs in (("cost_ratio", whole), ("loop_cost_ratio", loop)):
                ratios = [a / b for a, b in zip(costs[k], costs[(stack, 0)], strict=True)]
                results[f"{key}.{name}"] = round(statistics.median(ratios), 4)
    for n in COUNTS:
        if n:
            results[f"people.n{n}.crowd_ms_per_sim_s"] = round(_crowd_ms_per_sim_s(n), 3)
    return results
