"""A map_area task's life in a run: SLAM takes over pose and map, then the saved map
takes over navigation and localisation.

The runner makes one :class:`MapBuilder` and the tree hands it to ``map_area``'s
behaviour, which calls :meth:`MapBuilder.begin` and :meth:`MapBuilder.end`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agv_mission.geometry import Bounds, Pose2D
from agv_mission.mapping.crop import crop_to_known
from agv_mission.mapping.quality import map_quality
from agv_mission.mapping.session import MappingSession
from agv_mission.maps.costmap import Costmap
from agv_mission.maps.grid import OccupancyGrid
from agv_mission.maps.obstacle_layer import ObstacleLayer
from agv_mission.maps.ros_map import load_ros_map, save_ros_map
from agv_mission.missions.run.stack import RobotStack
from agv_mission.navigation.handle import RobotHandle
from agv_mission.navigation.navigator import Navigator


class MapBuilder:
    """Starts and ends mapping sessions for a run; keeps what each one produced."""

    def __init__(
        self,
        stack: RobotStack,
        navigator: Navigator,
        handle: RobotHandle,
        run_dir: Path | None,
        rows: list[tuple[float, ...]],
    ) -> None:
        self.stack, self.navigator, self.handle = stack, navigator, handle
        self.run_dir = run_dir
        self.rows = rows  # the run's trajectory rows (t, true x, true y, ...), growing
        self.session: MappingSession | None = None  # while a map_area task maps
        self.maps: list[dict[str, Any]] = []
        self.built_map: OccupancyGrid | None = None  # the last map saved

    def begin(self, bounds: Bounds | None) -> MappingSession:
        """SLAM takes over pose and map, starting from the current estimate."""
        loaded, setup = self.stack.loaded, self.stack.setup  # a fleet: this robot's own
        bounds = bounds or loaded.world.map.extent
        session = MappingSession(
            self.stack.new_slam(bounds), bounds, setup.robot.inscribed_radius, setup.stack.costmap
        )
        session.start(self._anchor(), self.stack.odom)
        self.session = session
        return session

    def _anchor(self) -> Pose2D:
        """The pose the new map is anchored at.

        A robot that has not moved since the start is where the mission said it is; a
        filter estimate there only adds its initial spread to every cell of the map.
        """
        if not self.stack.has_moved():
            return self.stack.setup.start
        return self.handle.state.estimate

    def end(self, stem: str) -> dict[str, Any]:
        """Save the map, judge it against the world, and navigate on it from now on."""
        session = self.session
        assert session is not None, "end() without begin()"
        loaded, setup = self.stack.loaded, self.stack.setup
        grid = crop_to_known(session.grid)  # what was seen, not SLAM's canvas
        summary: dict[str, Any] = {"map": stem}
        if self.run_dir is not None:
            save_ros_map(grid, self.run_dir / stem)
            grid = load_ros_map(self.run_dir / f"{stem}.yaml")  # navigate on what was saved
        quality = map_quality(
            grid, loaded.world.map, session.bounds, start=(setup.start.x, setup.start.y)
        )
        summary.update({k: round(v, 4) for k, v in quality.items()})
        summary["slam_rmse"] = round(self._slam_rmse(session), 4)
        summary["known_fraction"] = round(session.known_fraction(), 4)
        self.maps.append(summary)
        self.built_map = grid
        costmap_config = setup.stack.costmap
        static = Costmap.from_grid(grid, setup.robot.inscribed_radius, costmap_config)
        self.navigator.layer = ObstacleLayer(static, costmap_config.obstacles)
        self.stack.localizer = self.stack.new_localizer(grid)
        self.stack.localizer.reset(session.slam.pose, self.stack.odom)
        self.session = None
        return summary

    def _slam_rmse(self, session: MappingSession) -> float:
        """SLAM trajectory error against the true trajectory at the same times."""
        est = np.asarray(session.slam.trajectory, dtype=float).reshape(-1, 4)
        if not len(est) or not self.rows:
            return float("nan")
        rows = np.asarray(self.rows)
        idx = np.clip(np.searchsorted(rows[:, 0], est[:, 0] - 1e-9), 0, len(rows) - 1)
        err = np.hypot(est[:, 1] - rows[idx, 1], est[:, 2] - rows[idx, 2])
        return float(np.sqrt(np.mean(err**2)))
