"""Fault injection: the mission's ``faults:`` applied to the simulated robot, and a log of
which fired."""

from __future__ import annotations

from typing import Any

import numpy as np

from agv_mission.navigation.handle import RobotHandle
from agv_mission.robots.diff_drive import DiffDriveBody
from agv_mission.sensor_msgs import LaserScan


def _active(fault: Any, now: float) -> bool:
    return now >= fault.start - 1e-9 and (fault.end is None or now < fault.end - 1e-9)


class FaultInjector:
    """Applies faults at their times; every random draw comes from its own ``rng``."""

    def __init__(self, faults: list[Any], sim: DiffDriveBody, rng: np.random.Generator) -> None:
        self.faults = faults
        self.sim = sim
        self.rng = rng
        self.base_noise = sim.encoders.noise
        self.base_slip = sim.encoders.slip
        self.fired: list[dict[str, Any]] = [
            {"type": f.type, "fired": False, "first": None, "count": 0} for f in faults
        ]

    def _fire(self, i: int, now: float, handle: RobotHandle, **details: Any) -> None:
        log = self.fired[i]
        if not log["fired"]:
            log["fired"], log["first"] = True, round(now, 3)
            handle.log("fault", kind=self.faults[i].type, **details)
        log["count"] += 1

    def apply(self, now: float, handle: RobotHandle) -> None:
        """Set the encoder faults in force at ``now`` and carry out kidnaps that are due."""
        noise, slip = self.base_noise, self.base_slip
        for i, fault in enumerate(self.faults):
            if fault.type == "kidnap":
                if not self.fired[i]["fired"] and now >= fault.time - 1e-9:
                    pose = fault.pose.to_pose2d()
                    self.sim.teleport(pose)
                    self._fire(i, now, handle, x=pose.x, y=pose.y, yaw=pose.yaw)
            elif fault.type == "wheel_slip" and _active(fault, now):
                slip = max(slip, fault.factor)
                self._fire(i, now, handle)
            elif fault.type == "odometry_noise" and _active(fault, now):
                noise = noise * fault.scale if noise > 0 else 0.01 * fault.scale
                self._fire(i, now, handle)
        self.sim.encoders.noise, self.sim.encoders.slip = noise, slip

    def filter_scan(self, now: float, scan: LaserScan, handle: RobotHandle) -> LaserScan | None:
        """The scan, or ``None`` when a lidar dropout swallows it."""
        for i, fault in enumerate(self.faults):
            dropout = fault.type == "lidar_dropout" and _active(fault, now)
            if dropout and self.rng.random() < fault.rate:
                self._fire(i, now, handle)
                return None
        return scan

    def describe_fired(self) -> str:
        """``"kidnap at 30 s, lidar_dropout from 0 s"``: the faults that fired, for reasons."""
        return ", ".join(
            f"{log['type']} {'at' if log['type'] == 'kidnap' else 'from'} {log['first']:g} s"
            for log in self.fired
            if log["fired"]
        )

    def report(self) -> list[dict[str, Any]]:
        """Each fault of the mission: whether it fired, when first, and how often."""
        return [dict(log) for log in self.fired]
