"""Behaviour trees: what a tree costs beside the same mission as ``tasks:``.

* ``trees.patrol.tree_over_tasks_cost``: CPU seconds of a patrol (turtlebot3_world,
  ground truth, cost_grid, pure pursuit, two rounds) written as a hand-built tree
  (repeat > sequence > subtree calls of navigate_to_pose + wait) over the same patrol as
  a ``tasks:`` list, the two runs stepped side by side (``side_by_side.py``; whole runs
  one after the other read 1.0-1.17 for code whose instruction counts differ by 0.2 %),
  the median of three pairings. Every run must drive the trajectory it drives alone
  (``same_trajectory``).
* ``trees.<mission>.tree_ms_per_sim_s``: the tree's own CPU per simulated second: the time
  inside the root's tick minus the navigator's (planning and the local planner are the
  stack's cost, whoever calls them), per simulated second.
* ``trees.assemble_10k_nodes_ms``: validating and expanding a tree of 8 200 nodes (subtree
  fan-out), near the 10 000 a mission may hold.
* ``trees.nav2_jazzy.*``: Nav2's Jazzy navigator tree
  (``navigate_to_pose_w_replanning_and_recovery.xml``, as shipped: replanning at 1 Hz)
  driving the burger from the living room to the kitchen of the house (amcl, cost_grid,
  MPC), against our ``navigate_to_pose`` to the same goal; alternated twice, each keeping
  its fastest: the Nav2 tree's real-time factor (simulated over wall seconds), CPU
  seconds over ours, and how many times it planned.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
from side_by_side import paired_ratio

from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.runner import MissionRun

REPO = Path(__file__).resolve().parents[1]
HEAD = """\
world: turtlebot3_world
robot: burger
start: {x: -2.0, y: -0.5, yaw: 0.0}
seed: 2
stack:
  localization: {type: ground_truth}
  global_planner: {type: cost_grid}
  local_planner: {type: pure_pursuit}
limits: {time: 200.0}
"""
WAYPOINTS = ["{x: 0.5, y: -1.6, yaw: 0.0}", "{x: -2.0, y: 0.6, yaw: 1.57}"]
TASKS = (
    HEAD
    + f"""\
tasks:
  - type: patrol
    waypoints: [{", ".join(WAYPOINTS)}]
    loops: 2
    dwell: 1.0
"""
)
TREE = (
    HEAD
    + f"""\
blackboard: {{first: {WAYPOINTS[0]}, second: {WAYPOINTS[1]}}}
trees:
  VisitAndWait:
    type: sequence
    children:
      - {{type: navigate_to_pose, name: go, goal: "{{goal}}"}}
      - {{type: wait, name: dwell, seconds: 1.0}}
tree:
  type: repeat
  num_cycles: 2
  child:
    type: sequence
    children:
      - {{type: subtree, id: VisitAndWait, goal: "{{first}}"}}
      - {{type: subtree, id: VisitAndWait, goal: "{{second}}"}}
"""
)


def _timed(fn: Any, totals: list[float]) -> Any:
    def wrapped(*args: Any, **kwargs: Any) -> Any:
        t = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            totals[0] += time.process_time() - t

    return wrapped


def _run(path: Path) -> tuple[float, float, np.ndarray, str]:
    """(CPU s of the whole run, the tree's own CPU s, trajectory, status)."""
    loaded = load_mission(path)
    start = time.process_time()
    run = MissionRun(loaded, None)
    tick, nav = [0.0], [0.0]
    run.tree.root.tick_once = _timed(run.tree.root.tick_once, tick)  # type: ignore[method-assign]
    for name in ("update", "start", "cancel"):
        setattr(run.navigator, name, _timed(getattr(run.navigator, name), nav))
    run.drive()
    cpu = time.process_time() - start
    record = run.record()
    return cpu, tick[0] - nav[0], record.trajectory, record.status


def _tree_over_tasks(tasks: Path, tree: Path) -> tuple[float, bool]:
    """The tree's CPU over the tasks' (see the module's docstring), and whether every run
    drove its trajectory of a run alone."""
    alone = {"a": _run(tasks)[2], "b": _run(tree)[2]}
    same = [True]

    def check(kind: str, record: Any) -> None:
        same[0] &= record.status == "succeeded" and np.array_equal(record.trajectory, alone[kind])

    ratio = paired_ratio(
        lambda: MissionRun(load_mission(tasks), None),
        lambda: MissionRun(load_mission(tree), None),
        check=check,
    )
    return ratio, same[0]


NAV2_TREE = (
    REPO / "tests" / "nav2_trees" / "jazzy" / "navigate_to_pose_w_replanning_and_recovery.xml"
)
HOUSE = "world: small_house\nrobot: burger\nstart: livingroom\nseed: 1\nlimits: {time: 120.0}\n"


def _nav2(base: Path) -> dict[str, float]:
    (base / "nav2.yaml").write_text(
        HOUSE + f"tree: {{type: navigate_to_pose, goal: kitchen, behavior_tree: {NAV2_TREE}}}\n"
    )
    (base / "ours.yaml").write_text(HOUSE + "tree: {type: navigate_to_pose, goal: kitchen}\n")
    cpu = {"nav2": np.inf, "ours": np.inf}
    rtf, plans = 0.0, 0
    for _ in range(2):
        for kind in ("nav2", "ours"):
            loaded = load_mission(base / f"{kind}.yaml")
            wall, start = time.perf_counter(), time.process_time()
            run = MissionRun(loaded, None)
            run.drive()
            used, wall = time.process_time() - start, time.perf_counter() - wall
            record = run.record()
            assert record.status == "succeeded", (kind, record.reason)
            cpu[kind] = min(cpu[kind], used)
            if kind == "nav2":
                rtf = max(rtf, record.sim_time / wall)
                plans = run.navigator.stats.plans
    return {
        "trees.nav2_jazzy.real_time_factor": round(rtf, 2),
        "trees.nav2_jazzy.cpu_over_ours": round(cpu["nav2"] / cpu["ours"], 3),
        "trees.nav2_jazzy.plans": float(plans),
    }


def run(tmp: Path | None = None) -> dict[str, float]:
    import tempfile

    from agv_mission.missions.load.tree_assembly import assemble
    from agv_mission.missions.load.tree_spec import TreeSource, yaml_spec

    results: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as folder:
        base = Path(folder)
        (base / "tasks.yaml").write_text(TASKS)
        (base / "tree.yaml").write_text(TREE)
        own = {"tasks": np.inf, "tree": np.inf}
        trajectories: dict[str, np.ndarray] = {}
        sim = 0.0
        for _ in range(3):
            for kind in ("tasks", "tree"):
                cpu, tree_cpu, traj, status = _run(base / f"{kind}.yaml")
                assert status == "succeeded", (kind, status)
                sim = float(traj[-1, 0])
                own[kind] = min(own[kind], tree_cpu / sim)
                trajectories[kind] = traj
        ratio, same = _tree_over_tasks(base / "tasks.yaml", base / "tree.yaml")
        results["trees.patrol.tree_over_tasks_cost"] = round(ratio, 4)
        results["trees.patrol.same_trajectory"] = float(
            same and np.array_equal(trajectories["tasks"], trajectories["tree"])
        )
        results["trees.patrol.sim_time_s"] = round(sim, 2)
        for kind in ("tasks", "tree"):
            results[f"trees.patrol_{kind}.tree_ms_per_sim_s"] = round(own[kind] * 1e3, 4)
        cpu, tree_cpu, traj, status = _run(REPO / "missions" / "wander_tree.yaml")
        results["trees.wander_tree.tree_ms_per_sim_s"] = round(tree_cpu / traj[-1, 0] * 1e3, 4)

        results.update(_nav2(base))

    fan = {"type": "sequence", "children": [{"type": "subtree", "id": "L1"}] * 9}
    trees = {
        f"L{i}": {"type": "sequence", "children": [{"type": "subtree", "id": f"L{i + 1}"}] * 9}
        for i in range(1, 3)
    }
    trees["L3"] = {"type": "sequence", "children": [{"type": "stop"}] * 9}
    start = time.perf_counter()
    source = TreeSource(
        yaml_spec(fan, ("tree",), "m.yaml", {}),
        {k: yaml_spec(v, ("trees", k), "m.yaml", {}) for k, v in trees.items()},
    )
    spec = assemble(source)
    results["trees.assemble_10k_nodes_ms"] = round((time.perf_counter() - start) * 1e3, 1)
    results["trees.assemble_10k_nodes_count"] = float(spec.count)
    return results
