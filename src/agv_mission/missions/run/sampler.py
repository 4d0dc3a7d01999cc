"""The :class:`~agv_mission.missions.run.observe.StepSample` of each control step, built only
when a run has observers (a plain run pays nothing for them)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from agv_mission.geometry import Pose2D
from agv_mission.localization.base import LocalizerDiagnostics
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.missions.run.behaviour_tree import MissionTree
from agv_mission.missions.run.map_building import MapBuilder
from agv_mission.missions.run.samples import StepSample, TreeNode, tree_nodes
from agv_mission.missions.run.stack import Sensing
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import Navigator
from agv_mission.robots.battery import Battery


class SampledRobot(Protocol):
    """What a sample is read from: a robot's parts as its run holds them
    (:class:`~agv_mission.missions.run.robot_run.RobotRun` is one)."""

    name: str
    navigator: Navigator
    handle: RobotHandle
    mapper: MapBuilder
    tree: MissionTree
    task_status: list[str]
    battery: Battery | None


class StepSampler:
    """Turns one control step of a :class:`~agv_mission.missions.run.robot_run.RobotRun` into a
    :class:`StepSample`: what changed since the previous step (a new plan, a filter update,
    a grown map, tree statuses) and what holds now."""

    def __init__(self, run: SampledRobot) -> None:
        self.run = run
        self.plans = 0
        self.filter_updates = -1
        self.map_integrations = -1
        self.built_map: OccupancyGrid | None = None
        self.events_sent = 0  # handle.events handed to the observers so far
        self.nodes: list[TreeNode] = tree_nodes(run.tree.root)
        self._behaviours = list(run.tree.root.iterate())
        self._statuses = [node.status for node in self._behaviours]

    def _new_events(self, events: list[dict]) -> list[dict]:
        """Every event logged since the last sample, wherever in the step it was logged
        (a fault before the tick, a scan filter while sensing, the tree, the end): the
        observers see each event of ``result.json`` exactly once."""
        new = events[self.events_sent :]
        self.events_sent = len(events)
        return new

    def sample(
        self,
        sensing: Sensing,
        estimate: Pose2D,
        v: float,
        w: float,
        covariance: np.ndarray | None,
        diagnostics: LocalizerDiagnostics | None,
    ) -> StepSample:
        """The step's sample; ``covariance`` and ``diagnostics`` are what the runner read
        from the localiser (or the SLAM session) after the tick, ``diagnostics`` ``None``
        while mapping."""
        run = self.run
        navigator, handle = run.navigator, run.handle
        plan = None
        if len(navigator.paths) != self.plans:
            self.plans = len(navigator.paths)
            plan = navigator.paths[-1]
        particles = grid = None
        mapping = run.mapper.session
        if mapping is not None:
            if mapping.slam.integrations != self.map_integrations:
                self.map_integrations = mapping.slam.integrations
                grid = mapping.grid
        elif diagnostics is not None and diagnostics.filter_updates != self.filter_updates:
            self.filter_updates = diagnostics.filter_updates
            particles = diagnostics.particles
        if run.mapper.built_map is not self.built_map:
            self.built_map = grid = run.mapper.built_map
        # Walk the tree again only when a status changed (statuses read in place are
        # cheap; a TreeNode list per step is not).
        statuses = [node.status for node in self._behaviours]
        changed = statuses != self._statuses
        if changed:
            nodes = tree_nodes(run.tree.root)
            changed = nodes != self.nodes
            self.nodes = nodes
            self._behaviours = list(run.tree.root.iterate())
            self._statuses = [node.status for node in self._behaviours]
        task = next((i for i, s in enumerate(run.task_status) if s == "running"), None)
        battery = run.battery
        scans = sensing.scans
        return StepSample(
            t=sensing.time,
            truth=sensing.truth,
            estimate=estimate,
            covariance=covariance,
            odom=sensing.odom,
            v=v,
            w=w,
            scan=scans[-1] if scans else None,
            scans=scans,
            particles=particles,
            plan=plan,
            horizon=navigator.horizon,
            goal=navigator.goal,
            grid=grid,
            events=self._new_events(handle.events),
            tree_nodes=self.nodes if changed else None,
            task_index=task,
            task_type=run.tree.task_nodes[task].type if task is not None else None,
            battery=battery.level if battery is not None else None,
            charging=battery is not None and battery.charging,
            docked=handle.docked.name if handle.docked is not None else None,
            robot=run.name,
            imu=sensing.imu_samples,
        )
