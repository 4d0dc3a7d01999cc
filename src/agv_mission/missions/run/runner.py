"""The simulation-clock loop over a world of robots: sensors -> estimator -> behaviour
tree -> wheels, for every robot, then physics once for all.

One control step every ``CONTROL_PERIOD`` simulated seconds: every robot reads its
encoders and (when due) its lidar, updates odometry and its localiser, ticks its tree once
and chooses a command within its acceleration limits; then the world advances one control
period. A lidar faster than the loop scans at its own times while the world advances; each
of those scans reaches the robot's localiser (with the odometry at its time), obstacle
layer and observers at the next step. A one-robot mission is a world with one robot. The
wall clock is read only to report speed.
"""

from __future__ import annotations

import gc
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from agv_mission.localization.base import Localizer
from agv_mission.maps.recorder import open_recorders
from agv_mission.missions.load.resolved import Layout, LoadedMission
from agv_mission.missions.run.behaviour_tree import MissionTree
from agv_mission.missions.run.errors import RunStopped
from agv_mission.missions.run.fleet_orders import FleetCoordinator, queue_fleet_tasks
from agv_mission.missions.run.forked_team import ForkedTeam
from agv_mission.missions.run.observe import (
    RobotStart,
    RunControl,
    RunObserver,
    RunStart,
)
from agv_mission.missions.run.outcome import OUTCOMES
from agv_mission.missions.run.people_record import PeopleRun
from agv_mission.missions.run.record import RunRecord, bare_record
from agv_mission.missions.run.robot_run import RobotRun
from agv_mission.missions.run.samples import StepSample, tree_nodes
from agv_mission.missions.run.stack import CONTROL_PERIOD, RobotStack, build_world
from agv_mission.missions.run.team import InlineTeam, RobotTeam, team_size
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import Navigator
from agv_mission.robots.diff_drive import DiffDriveBody

__all__ = ["MissionRun", "run_mission"]

ProgressCallback = Callable[[float, float], None]


def run_mission(
    loaded: LoadedMission,
    run_dir: Path | None = None,
    progress: ProgressCallback | None = None,
    *,
    observers: Sequence[RunObserver] = (),
    control: RunControl | None = None,
) -> RunRecord:
    """Run ``loaded`` in simulation until its tree finishes or its time limit passes.

    With ``run_dir``, recorded room poses go to ``run_dir/location_recorder.yaml`` as they
    are recorded (and to the mission's ``recorder`` file, when it names one). Ctrl-C or
    ``control`` cancelling ends the run with status ``aborted``; an exception inside it
    with status ``error``: either way a record of what happened so far comes back.
    ``observers`` see the start, every control step and the record (once).
    """
    wall_start = time.perf_counter()
    run: MissionRun | None = None
    ended: tuple[str, str] | None = None
    try:
        run = MissionRun(loaded, run_dir, observers)
        run.notify_start()
        run.drive(control, progress)
    except KeyboardInterrupt:
        ended = ("aborted", "interrupted by the user (Ctrl-C)")
    except RunStopped as exc:
        ended = ("aborted", exc.reason)
    except Exception as exc:  # the run directory must still say what happened
        ended = ("error", f"{type(exc).__name__}: {exc}")
    if run is None:  # the set-up itself failed or was stopped
        status, reason = ended or ("error", "the run could not be set up")
        record = bare_record(loaded, status, reason, time.perf_counter() - wall_start)
    else:
        if ended is not None:
            run.end(*ended)
        try:
            record = run.record()
        except Exception as exc:  # still a result, without the metrics
            record = bare_record(
                loaded,
                "error",
                f"{type(exc).__name__} while summarising the run: {exc}",
                time.perf_counter() - wall_start,
                sim_time=run.world.time,
            )
    for observer in observers:
        observer.on_end(record)
    return record


class MissionRun:
    """One mission in simulation: the world, its robots, the control loop's state, the
    outcome."""

    def __init__(
        self,
        loaded: LoadedMission,
        run_dir: Path | None,
        observers: Sequence[RunObserver] = (),
    ) -> None:
        # The fleet's tasks are released now: each joins its robot's tree, in their order.
        loaded, dispatched = queue_fleet_tasks(loaded)
        # a fleet has the fleet layer beside its robots, reading the paths they drive
        fleet = loaded.layout is Layout.FLEET
        self.outcome = OUTCOMES[loaded.layout]
        self.loaded = loaded
        self.mission = loaded.mission
        self.run_dir = run_dir
        self.observers = list(observers)
        self.world, stacks, crowd = build_world(loaded)
        recorders = open_recorders(run_dir, loaded.recorder)
        self.robots = [
            RobotRun(loaded, stack, run_dir, recorders, bool(self.observers), traffic=fleet)
            for stack in stacks
        ]
        self.by_name = {r.name: r for r in self.robots}
        # who decides where: here until :meth:`drive` forks robot processes
        self.team: RobotTeam = InlineTeam(self.robots, bool(self.observers))
        self._samples: list[StepSample] = []  # the latest step's, not yet observed
        self.people = PeopleRun(crowd, self.world) if crowd is not None else None
        # The fleet's own log (fleet.md): what the fleet layer dispatched, waits, deadlocks,
        # and the robots' contacts with each other.
        self.fleet_log: dict[str, Any] = {
            "dispatch": [{k: d[k] for k in ("task", "robot", "t")} for d in dispatched],
            "waits": {"count": 0, "time": 0.0},
            "deadlocks": 0,
            "robot_robot_collisions": [],
            "robot_robot_min_distance": math.inf,
            "makespan": None,
        }
        for d in dispatched:
            self.by_name[d["robot"]].handle.log(
                "dispatch", task=d["task"], type=d["type"], estimated_finish=d["finish"]
            )
        self.coordinator = (
            FleetCoordinator(
                [r.fleet_member() for r in self.robots],
                loaded.mission.fleet.traffic,
                self.fleet_log,
            )
            if fleet
            else None
        )
        self._touching: set[tuple[int, int]] = set()
        self.wall_start = time.perf_counter()
        self.status: str | None = None
        self.reason: str | None = None

    # The first robot's parts: a one-robot mission's only robot (teleop, VDA 5050 vehicles
    # and the service's teleop drive one robot).
    @property
    def lead(self) -> RobotRun:
        return self.robots[0]

    @property
    def sim(self) -> DiffDriveBody:
        return self.lead.sim

    @property
    def handle(self) -> RobotHandle:
        return self.lead.handle

    @property
    def navigator(self) -> Navigator:
        return self.lead.navigator

    @property
    def tree(self) -> MissionTree:
        return self.lead.tree

    @property
    def stack(self) -> RobotStack:
        return self.lead.stack

    @property
    def localizer(self) -> Localizer:
        return self.lead.localizer

    def notify_start(self) -> None:
        """Tell the observers what the run is about."""
        if not self.observers:
            return
        loaded = self.loaded
        robots = []
        for r in self.robots:
            zones = r.setup.zones
            robots.append(
                RobotStart(
                    name=r.name,
                    robot=r.robot,
                    start=r.setup.start,
                    tree_nodes=tree_nodes(r.tree.root),
                    keepout_mask=zones.keepout_grid() if zones and zones.keepout.any() else None,
                    speed_mask=zones.speed_grid() if zones and zones.levels else None,
                )
            )
        start = RunStart(
            run_dir=self.run_dir,
            mission=self.mission,
            world_map=loaded.map,
            rooms=loaded.rooms,
            docks=loaded.docks,
            robots=robots,
            fleet=loaded.layout is Layout.FLEET,
        )
        for observer in self.observers:
            observer.on_start(start)

    def drive(
        self, control: RunControl | None = None, progress: ProgressCallback | None = None
    ) -> None:
        """Step until the mission ends: ``control`` before each step, ``progress`` after.

        The set-up left ~100k long-lived objects (casadi functions, OMPL, typestores, the
        trees); the loop freezes them out of the garbage collector, so its one full
        collection of a 100 s run (~50 ms, 0.5 ms per simulated second) scans only what
        the run made since.
        """
        gc.freeze()
        size = team_size(self.mission.simulation.processes, len(self.robots), control)
        if size > 1 and self.team.processes == 1 and self.status is None:
            # a lidar scanning between control steps needs the physics there: stepped
            # in every process then, else only in this one and mirrored
            mirror = all(r.stack.scan_period >= CONTROL_PERIOD - 1e-9 for r in self.robots)
            world = self.world if mirror else None
            self.team = ForkedTeam.fork(self.robots, size, bool(self.observers), self._serve, world)
        try:
            while True:
                if control is not None:
                    control.before_step(self)
                if not self.step():
                    break
                if progress is not None:
                    progress(self.world.time, self.mission.limits.time)
            self._observe()
        finally:
            gc.unfreeze()

    def _observe(self) -> None:
        """Hand the observers the samples of the latest step not yet observed."""
        batch, self._samples = self._samples, []
        for sample in batch:
            for observer in self.observers:
                observer.on_step(sample)

    def _serve(self, team: ForkedTeam) -> None:
        """A robot process: step as the first process orders (it alone has observers)."""
        self.team = team  # the fork returns to the first process only
        self.observers = []
        team.serve(self.step, self.end, self._robot_record)

    def cancel(self, reason: str) -> None:
        """End the run with status ``aborted`` before the next control step."""
        self.end("aborted", reason)

    def step(self) -> bool:
        """One control step of every robot, then the world's physics; False once the
        mission has ended."""
        if self.status is not None:
            return False
        team = self.team
        now = team.clock(self.world)
        robots = self.robots
        coordinator = self.coordinator
        # the fleet layer decides in the first process; each robot's order reaches it
        # where it decides
        orders = team.begin_step(now, coordinator)
        self._observe()  # the step before's samples, while the robot processes decide
        for name, order in orders.items():  # each robot takes its own
            self.by_name[name].take_order(order)
        if self.people is not None:
            self.people.sense(now, robots)
        for r in robots:
            r.prepare(now)
        for r in team.own:
            r.decide(now)
        team.share_reports()
        self._watch_collisions(now)
        if len(robots) > 1:
            self._watch_robots(now)
        limit = self.mission.limits.time
        for r in team.own:
            r.conclude(now, limit)
        samples = team.share_outcomes()
        if self.status is None and all(r.status is not None for r in robots):
            self._conclude()
        if self.observers:
            batch = []
            for k in range(len(robots)):
                sample = samples.get(k)
                if sample is not None and k == 0 and self.people is not None:
                    sample.people = self.people.present()
                if sample is not None:
                    batch.append(sample)
            self._samples = batch
            if not team.observe_later:  # else once the next step is under way
                self._observe()
        if self.status is not None:
            return False
        for r in robots:
            r.act()
        self._advance()
        return True

    def _advance(self) -> None:
        """Let physics run one control period; lidars faster than the loop scan at their
        own times within it (to the physics step)."""
        world = self.world
        if self.people is not None:
            self.people.move(CONTROL_PERIOD, self.robots)
        self.team.advance(world, int(round(CONTROL_PERIOD / world.dt)))

    def _watch_collisions(self, now: float) -> None:
        """End the run once the robots together touched walls more often than allowed."""
        touched = [r for r in self.robots if r.new_collision is not None]
        if not touched:
            return
        total = sum(len(r.collisions) for r in self.robots)
        total += len(self.fleet_log["robot_robot_collisions"])
        if total > self.mission.limits.collisions:
            r = touched[0]
            c = r.new_collision
            assert c is not None
            where = f"collision at t={now:.1f} s near ({c['x']:.2f}, {c['y']:.2f})"
            self.end("failed", self.outcome.says(r, where))

    def _watch_robots(self, now: float) -> None:
        """Robot-robot contacts (each new touch counts once) and the closest approach."""
        log = self.fleet_log
        gap = float(self.world.body_gaps().min())
        log["robot_robot_min_distance"] = min(log["robot_robot_min_distance"], gap)
        touching = {pair for pair in self.world.contacts() if pair[1] >= 0}
        for i, j in sorted(touching - self._touching):
            a, b = self.robots[i], self.robots[j]
            x, y = self.world.position(i)  # where the first of the two stands
            log["robot_robot_collisions"].append(
                {"t": round(now, 3), "robots": [a.name, b.name], "x": round(x, 3), "y": round(y, 3)}
            )
            a.handle.log("robot_collision", robot=a.name, other=b.name)
            if len(log["robot_robot_collisions"]) > self.mission.limits.collisions:
                self.end(
                    "failed",
                    f"{a.name} and {b.name} collided at t={now:.1f} s near ({x:.2f}, {y:.2f})",
                )
        self._touching = touching

    def _conclude(self) -> None:
        """Every robot's part has ended: the mission's outcome."""
        failed = [r for r in self.robots if r.status != "succeeded"]
        self.fleet_log["makespan"] = round(self.world.time, 3)
        if not failed:
            self.status, self.reason = "succeeded", None
        else:
            self.status, self.reason = self.outcome.concluded(failed[0])

    def end(self, status: str, reason: str | None) -> bool:
        """End the run (the first outcome stands); robots still running end with it."""
        if self.status is None:
            for r in self.robots:
                r.end(status, reason)
            self.status, self.reason = self.outcome.ended(self.robots[0], status, reason)
        return False

    def _robot_record(self, k: int, wall_time: float) -> RunRecord:
        """Robot ``k``'s record, with its ``metrics.people`` (made where it decided)."""
        r = self.robots[k]
        record = r.record(wall_time)
        if self.people is not None:
            record.metrics["people"] = self.people.metrics(
                k,
                record.trajectory,
                r.robot.footprint_radius,
                r.navigator.stats.legs,
                self.world.time,
            )
        return record

    def record(self) -> RunRecord:
        """The outcome so far, as the run directory will hold it."""
        if self.status is None:
            self.end("error", "the run ended without an outcome")
        self._observe()
        wall_time = time.perf_counter() - self.wall_start
        team = self.team
        assert self.status is not None
        remote = team.gather((self.status, self.reason), wall_time)
        records = [
            remote[k] if k in remote else self._robot_record(k, wall_time)
            for k in range(len(self.robots))
        ]
        return self.outcome.record(
            dict(zip((r.name for r in self.robots), records, strict=True)),
            (self.status or "error", self.reason),
            self.people,
            self.fleet_log,
            self.world.time,
            wall_time,
            processes=team.processes,  # the robots decided in (missions.run.team)
        )
