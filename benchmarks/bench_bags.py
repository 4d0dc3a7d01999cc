"""Bags: what writing one costs a run, how fast ``agv-mission map`` maps one, how good the
map is, and what loop closure buys on a 100 m loop.

* write: the demo patrol (amcl, MPC) without and with the bag writer, alternated in one
  process (the machine's speed flips 2x: compare within a pair), as the share of the run's
  wall time the bag adds, and megabytes per simulated minute;
* round trip: a ``map_area`` run of turtlebot3_world and a patrol through every room of
  the AWS small-house ROS map (``benchmarks/data/house_patrol.yaml``), each with the bag
  writer, the bag mapped offline by the default ``map`` SLAM: free-cell IoU against the
  world (and, for ``map_area``, the IoU of the map the run built live), scans per second
  and the speed as a multiple of the bag's duration;
* fleet write: warehouse fleets of 1 and 5 robots (amcl + MPC each, ``bench_fleet``'s
  aisle patrols), the writer's own time (its observer calls, which run between the
  robots' steps) in ms per robot per simulated second, and megabytes per robot per
  simulated minute (a namespaced robot should cost what a lone one does), and the share
  of the run's wall time the writer takes;
* loop: one lap (~100 m) of the loop building with slipping wheels (rosbots, 12 m lidar,
  ``benchmarks/data/loop_patrol.yaml``), mapped by ``grid`` (no loop closure) and by
  ``graph`` (loop closure): trajectory RMSE against ground truth.
"""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from agv_mission.bags.offline import default_slam, map_bag, slam_config
from agv_mission.bags.writer import BagWriter
from agv_mission.mapping.quality import map_quality
from agv_mission.missions.load.loader import load_mission
from agv_mission.missions.run.observe import RunObserver
from agv_mission.missions.run.runner import run_mission

HERE = Path(__file__).resolve().parent
REPO = HERE.parent


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _write_cost(root: Path) -> dict[str, float]:
    loaded = load_mission(REPO / "missions" / "patrol.yaml", ["limits.time=60"])
    walls: dict[bool, list[float]] = {False: [], True: []}
    size = 0
    sim = 0.0
    for i, bag in enumerate((False, True, False, True)):
        run_dir = root / f"write{i}"
        run_dir.mkdir()
        t0 = time.perf_counter()
        record = run_mission(loaded, run_dir, observers=[BagWriter()] if bag else [])
        walls[bag].append(time.perf_counter() - t0)
        sim = record.sim_time
        if bag:
            size = _size(run_dir / "bag")
    without, with_bag = min(walls[False]), min(walls[True])
    return {
        "bags.write.run_wall_s.without": round(without, 3),
        "bags.write.run_wall_s.with": round(with_bag, 3),
        "bags.write.cost_share": round((with_bag - without) / with_bag, 4),
        "bags.write.mb_per_sim_minute": round(size / 1e6 * 60.0 / sim, 3),
    }


class _Timed:
    """An observer with its calls timed (wall clock: they run alone, between the robots'
    steps)."""

    def __init__(self, observer: RunObserver) -> None:
        self.observer = observer
        self.seconds = 0.0

    def on_start(self, start: Any) -> None:
        t0 = time.perf_counter()
        self.observer.on_start(start)
        self.seconds += time.perf_counter() - t0

    def on_step(self, sample: Any) -> None:
        t0 = time.perf_counter()
        self.observer.on_step(sample)
        self.seconds += time.perf_counter() - t0

    def on_end(self, record: Any) -> None:
        t0 = time.perf_counter()
        self.observer.on_end(record)
        self.seconds += time.perf_counter() - t0


def _fleet_write(
    root: Path, sizes: tuple[int, ...] = (1, 5), sim: float = 20.0
) -> dict[str, float]:
    from bench_fleet import fleet_mission

    out: dict[str, float] = {}
    for n in sizes:
        path = root / f"fleet{n}.yaml"
        path.write_text(fleet_mission(n, sim))
        loaded = load_mission(path)
        run_dir = root / f"fleet{n}"
        run_dir.mkdir()
        writer = _Timed(BagWriter().prepare())
        record = run_mission(loaded, run_dir, observers=[writer])
        per = n * record.sim_time
        key = f"bags.fleet_write.robots{n}"
        out[f"{key}.writer_ms_per_robot_sim_s"] = round(writer.seconds * 1e3 / per, 3)
        out[f"{key}.share_of_run_wall"] = round(writer.seconds / record.wall_time, 4)
        out[f"{key}.mb_per_robot_sim_minute"] = round(_size(run_dir / "bag") / 1e6 * 60 / per, 3)
    return out


def _round_trip(root: Path, label: str, mission: Path) -> dict[str, float]:
    loaded = load_mission(mission)
    run_dir = root / label
    run_dir.mkdir()
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    result = map_bag(run_dir / "bag", default_slam([]))
    start = (loaded.start.x, loaded.start.y)
    quality = map_quality(result.grid, loaded.world.map, None, start)
    r = result.report
    key = f"bags.round_trip.{label}"
    out = {
        f"{key}.free_iou.offline": round(quality["free_iou"], 4),
        f"{key}.bag_duration_s": r["bag_duration"],
        f"{key}.map_wall_s": r["wall_time"],
        f"{key}.scans_per_s": r["scans_per_second"],
        f"{key}.x_bag_duration": r["speed_vs_real_time"],
    }
    if record.extras.get("maps"):
        out[f"{key}.free_iou.live_map_area"] = round(float(record.extras["maps"][0]["free_iou"]), 4)
    return out


def _loop(root: Path) -> dict[str, float]:
    loaded = load_mission(HERE / "data" / "loop_patrol.yaml")
    run_dir = root / "loop"
    run_dir.mkdir()
    record = run_mission(loaded, run_dir, observers=[BagWriter()])
    out: dict[str, float] = {"bags.loop.distance_m": record.metrics["distance_driven"]}
    for slam in ("grid", "graph"):
        result = map_bag(run_dir / "bag", slam_config([f"type={slam}"]))
        rmse = result.report["rmse"]
        out[f"bags.loop.{slam}.position_rmse"] = rmse["position_rmse"]
        out[f"bags.loop.{slam}.ate_aligned"] = rmse["ate_aligned"]
        out[f"bags.loop.{slam}.x_bag_duration"] = result.report["speed_vs_real_time"]
        if slam == "graph":
            out["bags.loop.graph.loop_closures"] = result.report["slam_diagnostics"][
                "loop_closures"
            ]
    return out


def run() -> dict[str, float]:
    root = Path(tempfile.mkdtemp(prefix="bench_bags_"))
    try:
        results = _write_cost(root)
        results |= _fleet_write(root)
        results |= _round_trip(root, "tb3", REPO / "tests" / "scenarios" / "map_area_tb3.yaml")
        results |= _round_trip(root, "aws_small_house", HERE / "data" / "house_patrol.yaml")
        results |= _loop(root)
        return results
    finally:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    for k, v in run().items():
        print(f"{k}: {v}")
