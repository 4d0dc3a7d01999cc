"""One robot's part of a run: its stack, navigator, tree, safety watch and record.

A :class:`RobotRun` senses, estimates and decides for one robot once per control step;
the run (:mod:`agv_mission.missions.run.runner`) steps the world they share and asks every
robot in turn. Robots never call each other.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
from py_trees.common import Status

from agv_mission.behaviors.context import TreeContext
from agv_mission.behaviors.outcome import failure_reason
from agv_mission.geometry import Pose2D
from agv_mission.localization.base import Localizer, LocalizerDiagnostics
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.maps.recorder import LocationRecorder
from agv_mission.maps.zones import zone_metrics
from agv_mission.missions.load.resolved import LoadedMission
from agv_mission.missions.run.behaviour_tree import build_tree
from agv_mission.missions.run.btlog import TreeLog
from agv_mission.missions.run.faults import FaultInjector
from agv_mission.missions.run.fleet_orders import FleetMember, FleetOrder
from agv_mission.missions.run.map_building import MapBuilder
from agv_mission.missions.run.metrics import (
    COVARIANCE_COLUMNS,
    add_true_errors,
    covariance_metrics,
    covariance_row,
    run_metrics,
    task_reports,
)
from agv_mission.missions.run.record import TRAJECTORY_COLUMNS, RunRecord
from agv_mission.missions.run.sampler import StepSampler
from agv_mission.missions.run.samples import RobotReport, StepSample, status_name
from agv_mission.missions.run.stack import CONTROL_PERIOD, RobotStack, Sensing
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import NavStatus
from agv_mission.navigation.scan_filter import beams_on_people
from agv_mission.navigation.state import RobotState
from agv_mission.planners.collision_monitor import CollisionMonitor
from agv_mission.robots.battery import Battery, battery_for
from agv_mission.sensor_msgs import LaserScan

#: Below this planar clearance (m) contacts are read (above, one needs a ~15 degree tilt).
CONTACT_CLEARANCE = 0.05


def _without(scan: LaserScan | None, on_people: np.ndarray | None) -> LaserScan | None:
    """The scan for the localiser (or SLAM) without the returns on tracked people (as a
    laser filter would take them out): a crowd is not on the map and would pull the
    estimate towards whatever it hides, or be mapped."""
    if scan is None or on_people is None or not on_people.any():
        return scan
    ranges = scan.ranges.copy()
    ranges[on_people] = np.inf
    return dataclasses.replace(scan, ranges=ranges)


def _vw(cmd: Any) -> tuple[float, float]:
    return float(cmd.v), float(cmd.w)


class RobotRun:
    """One robot in a run: what it senses, believes and does, step by step."""

    def __init__(
        self,
        loaded: LoadedMission,
        stack: RobotStack,
        run_dir: Path | None,
        recorders: list[LocationRecorder],
        observed: bool,
        traffic: bool = False,
    ) -> None:
        self.loaded = loaded
        self.stack = stack
        setup = stack.setup
        self.setup = setup
        self.name = setup.name
        self.mission, self.robot = loaded.mission, setup.robot
        robot = setup.robot
        self.sim, self.odometry, self.limits = stack.sim, stack.odometry, stack.limits
        self.navigator = stack.build_navigator()
        self.battery: Battery | None = None
        if robot.battery is not None:
            self.battery = battery_for(
                robot.battery,
                robot.mass,
                robot.footprint_radius,
                robot.wheel_separation,
                self.mission.simulation.battery_level,
            )
        self.handle = RobotHandle(
            RobotState(time=0.0, estimate=setup.start),
            self.navigator,
            rooms=loaded.rooms,
            recorders=recorders,
            battery=self.battery,
            docks=loaded.docks,
        )
        self.rows: list[tuple[float, ...]] = []
        self.levels: list[float] = []  # the battery's level at each step
        self.covs: list[tuple[float, ...]] = []
        self.mapper = MapBuilder(stack, self.navigator, self.handle, run_dir, self.rows)
        assert setup.tree is not None, "a robot to run has a tree"
        context = TreeContext(
            self.handle,
            robot,
            setup.stack.navigation,
            setup.room_goals,
            self.mapper,
            blackboard=dict(setup.tree.source.blackboard),
        )
        self.tree = build_tree(setup.tree, context)
        self.tree_log = TreeLog(setup.tree, self.tree, self.handle)
        aimed = [f for f in self.mission.faults if f.robot in (None, self.name)]
        self.faults = FaultInjector(aimed, self.sim, stack.fault_rng)
        self.monitor = CollisionMonitor(
            setup.stack.collision_monitor, robot.footprint_radius, CONTROL_PERIOD, robot.polygon
        )
        self.task_status = ["not_run"] * len(self.tree.tasks)
        self.collisions: list[dict[str, float]] = []
        self.in_contact = False
        self.min_clearance = math.inf
        self._clearance_at = (0.0, 0.0, -math.inf)  # (x, y, clearance) of the last query
        self.new_collision: dict[str, float] | None = None  # a wall touched this step
        self.status: str | None = None  # the robot's own outcome, once its tree ends
        self.reason: str | None = None
        self.sampler = StepSampler(self) if observed else None
        self.command = (0.0, 0.0)
        self.sensing: Sensing | None = None
        self.estimate = setup.start
        self._perceived: tuple[Pose2D, Pose2D] | None = None  # the last odometry, estimate
        self._covariance: np.ndarray | None = None
        self._diagnostics: LocalizerDiagnostics | None = None
        # What the others (the fleet layer, the run, other processes) read of this robot
        # after it decided: set by :meth:`decide`, or from a :class:`RobotReport`.
        self.traffic_path: np.ndarray | None = None  # the path it drives (fleets only)
        self.navigating = False  # its navigator drives to a goal
        self.yielding = False  # it steps aside for another robot
        self._traffic = traffic  # a fleet layer reads the path it drives

    @property
    def localizer(self) -> Localizer:
        return self.stack.localizer

    # ----------------------------------------------------------------- one control step
    def prepare(self, now: float) -> None:
        """What this step does to the world before any robot senses: faults (a kidnap
        moves the body)."""
        self.handle.state.time = now
        self.faults.apply(now, self.handle)

    def decide(self, now: float) -> None:
        """Sense, estimate, tick the tree and choose this step's command (not yet sent);
        touches only this robot and reads the world."""
        handle, state = self.handle, self.handle.state
        sensing = self.stack.sense(self._scan_filter)
        truth = sensing.truth
        for earlier in sensing.earlier:  # a lidar faster than the loop: each at its time
            self._perceive(earlier)
        estimate = self._perceive(sensing)
        state.time, state.estimate = now, estimate
        smoother = self.stack.smoother
        state.velocity = (smoother.v, smoother.w)

        handle.stop()
        self.navigator.horizon = None  # set again if the tick drives the local planner
        if self.status is None:
            self.tree.root.tick_once()
            for i, subtree in enumerate(self.tree.tasks):
                if subtree.status is not Status.INVALID:
                    self.task_status[i] = status_name(subtree.status)
        navigator = self.navigator
        if navigator.yielding and not navigator.updated_at(now):
            # stepping aside for another robot while no behaviour drives (its tree is
            # done, or it waits, docks, ...): the fleet layer's order stands
            handle.drive(*_vw(navigator.update(state)))
        v, w = self._monitored(estimate, *self._speed_capped(estimate, *handle.command))
        v, w = smoother(v, w)
        battery = self.battery
        if battery is not None:
            self.levels.append(battery.level)
            if battery.level <= 0.0 and self.status is None:
                v = w = 0.0
                self.end(
                    "failed",
                    f"battery empty at t={now:.1f} s "
                    f"({battery.energy_used / 3600.0:.2f} Wh used): the robot stopped",
                )
        self.rows.append(
            (now, truth.x, truth.y, truth.yaw, estimate.x, estimate.y, estimate.yaw, v, w)
        )
        covariance, diagnostics = self._estimate_covariance()
        self.covs.append(covariance_row(covariance))
        self._watch_safety(now, truth)
        self.sensing, self.estimate, self.command = sensing, estimate, (v, w)
        self._covariance, self._diagnostics = covariance, diagnostics
        self.yielding = navigator.yielding
        if self._traffic:
            self.traffic_path = navigator.traffic_path()
            self.navigating = navigator.status is NavStatus.RUNNING

    def conclude(self, now: float, limit: float) -> None:
        """The robot's outcome once its tree has ended or the time limit has come."""
        if self.status is not None:
            return
        root = self.tree.root.status
        if root is Status.SUCCESS:
            self.end("succeeded", None)
        elif root is Status.FAILURE:
            self.end("failed", self._failure())
        elif now >= limit - 1e-9:
            if self.tree.repeats_until_the_limit():
                self.handle.log("time_limit", reason="the tree repeats until the time limit")
                self.end("succeeded", None)
            else:
                self.end("failed", self._timeout())

    def sample(self) -> StepSample | None:
        """The step's sample for the observers (None when nobody watches)."""
        if self.sampler is None or self.sensing is None:
            return None
        v, w = self.command
        return self.sampler.sample(
            self.sensing, self.estimate, v, w, self._covariance, self._diagnostics
        )

    def act(self) -> None:
        """Send this step's command to the wheels (zero once the robot's part has ended)."""
        v, w = self.command if self.status is None or self.yielding else (0.0, 0.0)
        self.sim.set_command(v, w)
        if self.battery is not None:
            self.battery.step(v, w, CONTROL_PERIOD)

    def report(self) -> RobotReport:
        """What the others read of this robot once it decided (for robots deciding in other
        processes)."""
        return RobotReport(
            self.command,
            self.estimate,
            self.status,
            self.reason,
            self.new_collision,
            self.yielding,
            self.navigating,
            self.traffic_path,
        )

    def take_order(self, order: FleetOrder) -> None:
        """The fleet layer's order for this step: the traffic decision the navigator obeys,
        the other robots' bodies (its obstacle layer must not mark them), its fleet events."""
        self.navigator.fleet_bodies = order.bodies
        self.navigator.obey(order.decision, self.handle.state)
        self.handle.events.extend(order.events)

    def fleet_member(self) -> FleetMember:
        """This robot as the fleet layer knows it for the whole run."""
        return FleetMember(
            self.name, self.robot.footprint_radius, self.limits.max_v, self.setup.costmap
        )

    def take_report(self, report: RobotReport) -> None:
        """Stand for a robot deciding in another process: its report is all that is read
        of it here (its own parts stay as they were built)."""
        self.command, self.estimate = report.command, report.estimate
        self.status, self.reason = report.status, report.reason
        self.new_collision = report.new_collision
        if report.new_collision is not None:
            self.collisions.append(report.new_collision)
        self.yielding, self.navigating = report.yielding, report.navigating
        self.traffic_path = report.traffic_path

    def _monitored(self, estimate: Pose2D, v: float, w: float) -> tuple[float, float]:
        """The command through the collision monitor, on the newest scan's points in the
        robot's frame; each change of its action is an event."""
        points = self.handle.state.obstacles
        if points is None or not len(points):
            local = np.zeros((0, 2))
        else:
            dx, dy = points[:, 0] - estimate.x, points[:, 1] - estimate.y
            near = dx * dx + dy * dy <= self.monitor.reach(v) ** 2
            dx, dy = dx[near], dy[near]
            c, s = math.cos(estimate.yaw), math.sin(estimate.yaw)
            local = np.column_stack([c * dx + s * dy, -s * dx + c * dy])
        out = self.monitor(v, w, local)
        if self.monitor.changed:
            self.handle.log("collision_monitor", action=out.action, zone=out.zone)
        return out.v, out.w

    def _speed_capped(self, estimate: Pose2D, v: float, w: float) -> tuple[float, float]:
        """The command within the speed zones' limits (Nav2's speed filter), scaled as a
        whole so the robot keeps its curvature."""
        zones = self.setup.zones
        if zones is None or not zones.levels:
            return v, w
        lead = 2.0 * abs(self.stack.smoother.v) * CONTROL_PERIOD + zones.grid.resolution
        cap = zones.speed_cap(estimate.x, estimate.y, self.limits.max_acc_v, lead)
        if abs(v) <= cap:
            return v, w
        scale = cap / abs(v)
        return v * scale, w * scale

    def _scan_filter(self, t: float, scan: LaserScan) -> LaserScan | None:
        return self.faults.filter_scan(t, scan, self.handle)

    def _perceive(self, sensing: Sensing) -> Pose2D:
        """Odometry and a scan (if any) into the localiser or the SLAM session, and the
        scan into the obstacle layer, at the sensing's own time; the estimate then."""
        handle, scan, t = self.handle, sensing.scan, sensing.time
        mapping = self.mapper.session
        people = handle.state.people
        # the beams on tracked people, once for the localiser and the obstacle layer, seen
        # from the last estimate moved on by the odometry since (a robot turning in place
        # turns a beam by up to 0.3 rad a step: at 1.5 m a person's width)
        on_people = None
        if scan is not None and len(people):
            seen_from = self.estimate
            if self._perceived is not None:
                odom, estimate = self._perceived
                seen_from = estimate.compose(sensing.odom.relative_to(odom))
            seen_from = self.setup.robot.lidar.scan_pose(seen_from)  # from the mount
            on_people = beams_on_people(scan, seen_from, np.asarray(people, dtype=float))
        if mapping is not None:
            estimate = mapping.update(sensing.odom, _without(scan, on_people), sensing.truth, t)
            costmap = mapping.refreshed_costmap(t)
            if costmap is not None:
                self.navigator.layer = ObstacleLayer(costmap, costmap.config.obstacles)
        else:
            if handle.nomotion_update:  # the localiser holds it until a scan comes
                self.localizer.request_nomotion_update()
                handle.nomotion_update = False
            # other robots are not in the map: their returns are left out (fleet layer),
            # and so are tracked people's
            seen = (
                scan if scan is None else self.navigator.without_fleet(handle.state.estimate, scan)
            )
            estimate = self.localizer.update(
                sensing.odom, _without(seen, on_people), sensing.truth, t
            )
        if scan is not None:
            handle.state.scan = scan
            sensor = self.setup.robot.lidar.scan_pose(estimate)
            handle.state.obstacles = scan.points(sensor)
            # returns on people are not obstacles of the costmap: people standing are
            # marked as themselves, from the tracker (the scan's pose: the lidar's mount)
            self.navigator.observe(sensor, scan, people, on_people)
        self._perceived = (sensing.odom, estimate)
        return estimate

    def _estimate_covariance(self) -> tuple[np.ndarray | None, LocalizerDiagnostics | None]:
        """The current estimate's covariance: SLAM's while mapping, else the localiser's
        (with the localiser's diagnostics, read once per step)."""
        mapping = self.mapper.session
        if mapping is not None:
            return mapping.slam.covariance, None
        diagnostics = self.localizer.diagnostics()
        return diagnostics.covariance, diagnostics

    def end(self, status: str, reason: str | None) -> None:
        """The robot's own outcome (the first one stands); its wheels stop."""
        if self.status is None:
            fired = self.faults.describe_fired()
            if status == "failed" and fired:
                reason = f"{reason} (faults fired: {fired})"
            self.status, self.reason = status, reason
            self.sim.set_command(0.0, 0.0)

    def _watch_safety(self, now: float, truth: Pose2D) -> None:
        # The circle's clearance is 1-Lipschitz in the position and holds the body: a step
        # that cannot lower the minimum skips the query, or touch a wall the contacts.
        x0, y0, c0 = self._clearance_at
        bound = c0 - math.hypot(truth.x - x0, truth.y - y0)
        contacts = self.sim.contacts() if bound < CONTACT_CLEARANCE else 0
        self.new_collision = None
        if contacts and not self.in_contact:
            x, y = round(truth.x, 3), round(truth.y, 3)
            self.new_collision = {"t": round(now, 3), "x": x, "y": y}
            self.collisions.append(self.new_collision)
        self.in_contact = contacts > 0
        if bound < self.min_clearance:  # the footprint's clearance >= the circle's
            circle, clearance = self.sim.clearances()
            self._clearance_at = (truth.x, truth.y, circle)
            self.min_clearance = min(self.min_clearance, clearance)

    def _failure(self) -> str:
        i = next((i for i, s in enumerate(self.task_status) if s == "failed"), None)
        if i is None:
            return f"the tree failed: {failure_reason(self.tree.root)}"
        return (
            f"task {i + 1} ({self.tree.task_nodes[i].type}) failed: "
            f"{failure_reason(self.tree.tasks[i])}"
        )

    def _timeout(self) -> str:
        i = next((i for i, s in enumerate(self.task_status) if s == "running"), None)
        limit = self.mission.limits.time
        if i is None:
            return f"time limit of {limit:g} s reached"
        self.task_status[i] = "failed"
        self.tree.tasks[i].feedback_message = "time limit reached"
        return (
            f"time limit of {limit:g} s reached during task {i + 1} "
            f"({self.tree.task_nodes[i].type})"
        )

    def record(self, wall_time: float) -> RunRecord:
        """The robot's outcome so far, as the run directory will hold it."""
        if self.status is None:
            self.end("error", "the run ended without an outcome")
        sim_time = self.sim.time
        trajectory = np.asarray(self.rows, dtype=float).reshape(-1, len(TRAJECTORY_COLUMNS))
        if self.status in ("aborted", "error"):
            self.task_status = ["aborted" if s == "running" else s for s in self.task_status]
        elif self.status == "failed":  # e.g. a collision ended the run during this task
            for i, s in enumerate(self.task_status):
                if s == "running":
                    self.task_status[i] = "failed"
                    self.tree.tasks[i].feedback_message = self.reason or "mission failed"
        tasks = task_reports(self.tree, self.task_status, self.handle.events)
        add_true_errors(tasks, trajectory)
        covariance = np.asarray(self.covs, dtype=float).reshape(-1, len(COVARIANCE_COLUMNS))
        metrics = run_metrics(
            trajectory,
            self.navigator,
            len(self.collisions),
            self.min_clearance,
            sim_time,
            wall_time,
        )
        recoveries: dict[str, int] = {}
        for e in self.handle.events:
            if e["event"] == "recovery":
                recoveries[e["kind"]] = recoveries.get(e["kind"], 0) + 1
        metrics["navigation"]["recoveries"] = recoveries
        metrics["battery"] = self._battery_metrics()
        metrics["collision_monitor"] = self.monitor.report()
        zones = self.setup.zones  # its own: a speed zone is grown by its footprint
        metrics["zones"] = (
            zone_metrics(zones, trajectory[:, 0], trajectory[:, 1:3]) if zones is not None else None
        )
        metrics["localization"].update(covariance_metrics(trajectory, covariance))
        refine = getattr(self.localizer, "refine_stats", None)
        if refine and refine.get("scans"):
            metrics["localization"]["refinement"] = dict(refine)
        extras: dict[str, Any] = {
            "collisions": self.collisions,
            "faults": self.faults.report(),
            "tree": self.tree.report(),
        }
        if self.mapper.maps:
            extras["maps"] = self.mapper.maps
        if self.handle.recorded:
            extras["rooms_recorded"] = {
                label: {"x": round(p.x, 4), "y": round(p.y, 4), "yaw": round(p.yaw, 4)}
                for label, p in self.handle.recorded.items()
            }
        diagnostics = self.localizer.diagnostics()
        counts = diagnostics.particle_counts
        if counts:
            c = np.asarray([n for _, n in counts])
            metrics["localization"]["particles"] = {
                "min": int(c.min()),
                "max": int(c.max()),
                "mean": round(float(c.mean()), 1),
            }
            extras["particle_counts"] = [[round(t, 3), int(n)] for t, n in counts]
        return RunRecord(
            status=self.status or "error",
            reason=self.reason,
            sim_time=round(sim_time, 6),
            wall_time=round(wall_time, 3),
            tasks=tasks,
            metrics=metrics,
            trajectory=trajectory,
            covariance=covariance if np.isfinite(covariance).any() else None,
            paths=self.navigator.paths,
            events=self.handle.events,
            tree_text=self.tree.render(),
            btlog=self.tree_log.to_bytes(),
            extras=extras,
            particle_snapshots=list(diagnostics.snapshots),
            built_map=self.mapper.built_map,
            battery=np.asarray(self.levels, dtype=float) if self.battery is not None else None,
        )

    def _battery_metrics(self) -> dict[str, Any] | None:
        """``metrics.battery``: levels, energy, charging time, and how often it docked."""
        if self.battery is None:
            return None
        report: dict[str, Any] = self.battery.report()
        report["dockings"] = sum(1 for e in self.handle.events if e["event"] == "docked")
        return report
