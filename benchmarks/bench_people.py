"""What people cost a run (issue 25): one burger patrolling the built-in 30 x 50 m warehouse
with 0, 10 and 50 people wandering it, with the default stack (amcl and the MPC: what a
user's run costs) and with a perfect localiser (``ground_truth``: the robot's own software
cheaper, so people's share larger), everything a ``agv-mission run`` does included (the
crowd, their bodies in the physics and the lidar's rays, the bag's ``/people``,
``people.csv``, ``run.png``) over 120 simulated seconds.

This machine's speed moves by 20-40 % within seconds, so a run with people and the same
run without them (same seed) are stepped side by side in one process, a control step of
one then a control step of the other: both see the machine as it is at every step, and
their thread CPU times are compared as a ratio per seed (median over the seeds: who meets
the robot where, and so what they cost it, varies with the seed). ``*.loop_cost_ratio``
is the control loop alone (what ``result.json``'s ``wall_time`` measures, but the set-up);
``*.cost_ratio`` the whole run, set-up and run directory included. ``people.cli.*`` is
what a user sees: ``agv-mission run`` in a fresh process, its CPU time (user + system,
interpreter start and imports included), the two runs alternated."""

from __future__ import annotations

import gc
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from agv_mission.bags.writer import BagWriter
from agv_mission.maps.builtin_worlds import warehouse
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.report.outputs import write_run
from agv_mission.missions.run.runner import MissionRun
from agv_mission.world.crowd import Crowd
from agv_mission.world.people_groups import PeopleGroup

SEEDS = (5, 6, 7, 8)  # a pair of runs each
CLI_SEEDS = (5, 6, 7)
SIM_SECONDS = 120.0
COUNTS = (10, 50)
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


class _Timed:
    """One run of a pair: its set-up, control loop and run directory, each in thread CPU
    seconds, the bag written as ``agv-mission run`` writes it."""

    def __init__(self, path: Path, out: Path) -> None:
        self.loaded = load_mission(path)
        self.run_dir = out / f"{path.stem}_{len(list(out.iterdir()))}"
        self.run_dir.mkdir()
        self.writer = BagWriter(self.run_dir / "bag").prepare()
        self.setup = self.loop = self.post = 0.0
        t = time.thread_time()
        self.run = MissionRun(self.loaded, self.run_dir, [self.writer])
        self.run.notify_start()
        self.setup = time.thread_time() - t

    def step(self) -> bool:
        t = time.thread_time()
        going = self.run.step()
        self.loop += time.thread_time() - t
        return going

    def finish(self) -> None:
        t = time.thread_time()
        record = self.run.record()
        self.writer.on_end(record)
        write_run(self.run_dir, self.loaded, record)
        self.post = time.thread_time() - t

    def per_sim_s(self) -> tuple[float, float]:
        """(whole run, loop) CPU seconds per simulated second."""
        sim = max(self.run.world.time, 1e-9)
        return (self.setup + self.loop + self.post) / sim, self.loop / sim


def _pair(tmp: Path, count: int, stack: str, seed: int) -> tuple[_Timed, _Timed]:
    """The run without people and the run with ``count``, stepped side by side (their
    steps as ``MissionRun.drive`` takes them, one run's then the other's)."""
    runs = (
        _Timed(_mission(tmp, 0, stack, seed), tmp),
        _Timed(_mission(tmp, count, stack, seed), tmp),
    )
    going = [True, True]
    gc.freeze()  # as MissionRun.drive does: the set-up's objects out of the collector's way
    try:
        while any(going):
            for k, run in enumerate(runs):
                if going[k]:
                    going[k] = run.step()
    finally:
        gc.unfreeze()
    for run in runs:
        run.finish()
    return runs


def _cli_cpu(path: Path, out: Path) -> float:
    """CPU seconds (user + system) of ``agv-mission run path`` in a fresh process."""
    exe = Path(sys.executable).parent / "agv-mission"
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run([str(exe), "run", str(path), "--output", str(out)], capture_output=True)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _crowd_ms_per_sim_s(count: int) -> float:
    """The crowd's own step (ORCA and routing) for ``count`` people, per simulated second,
    with its caches warm (in a run the robot's software between its steps costs it more)."""
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
    costs); ``people.ground_truth.nN.*``: the same with a perfect localiser;
    ``people.cli.n50.*``: fresh ``agv-mission run`` processes."""
    results: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        _pair(tmp_path, 50, "default", 5)  # warm the caches (casadi, typestore, matplotlib)
        for stack in STACKS:
            for n in COUNTS:
                key = f"people.n{n}" if stack == "default" else f"people.{stack}.n{n}"
                pairs = [_pair(tmp_path, n, stack, seed) for seed in SEEDS]
                base = [a.per_sim_s() for a, _ in pairs]
                with_people = [b.per_sim_s() for _, b in pairs]
                whole = [b[0] / a[0] for a, b in zip(base, with_people, strict=True)]
                loop = [b[1] / a[1] for a, b in zip(base, with_people, strict=True)]
                results[f"{key}.cost_ratio"] = round(statistics.median(whole), 4)
                results[f"{key}.cost_ratio_max"] = round(max(whole), 4)
                results[f"{key}.loop_cost_ratio"] = round(statistics.median(loop), 4)
                results[f"{key}.cpu_ms_per_sim_s"] = round(
                    statistics.median(b[0] for b in with_people) * 1e3, 3
                )
                results[f"{key}.base_cpu_ms_per_sim_s"] = round(
                    statistics.median(a[0] for a in base) * 1e3, 3
                )
                results[f"{key}.setup_ms"] = round(
                    statistics.median(b.setup for _, b in pairs) * 1e3, 1
                )
        cli = []
        for seed in CLI_SEEDS:
            without = _cli_cpu(_mission(tmp_path, 0, "default", seed), tmp_path / "cli")
            with_50 = _cli_cpu(_mission(tmp_path, 50, "default", seed), tmp_path / "cli")
            cli.append((without, with_50))
        results["people.cli.n50.cost_ratio"] = round(statistics.median(b / a for a, b in cli), 4)
        results["people.cli.n0.cpu_s"] = round(statistics.median(a for a, _ in cli), 2)
    for n in COUNTS:
        results[f"people.n{n}.crowd_ms_per_sim_s"] = round(_crowd_ms_per_sim_s(n), 3)
    return results
