"""Navigation parameters: tolerances, replanning and progress checking."""

from __future__ import annotations

import math
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class NavigationConfig(BaseModel):
    """How a goal is pursued (the mission's ``stack.navigation`` block)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    xy_goal_tolerance: float = Field(0.05, gt=0, description="metres")
    yaw_goal_tolerance: float = Field(0.05, gt=0, description="radians")
    replan_distance: float = Field(
        0.4, gt=0, description="replan when the robot strays this far from its path, m"
    )
    progress_distance: float = Field(0.1, gt=0, description="metres that count as progress")
    progress_timeout: float = Field(
        10.0, gt=0, description="simulated seconds without progress before replanning"
    )
    max_replans: int = Field(3, ge=0, description="replans per goal before the goal fails")
    obstacle_range: float = Field(
        1.5, gt=0, description="lidar points within this range go to the local planner, m"
    )
    escape_distance: float = Field(
        0.3, gt=0, description="how far the robot may move to reach such a start, m"
    )
    blocked_lookahead: float = Field(
        2.0, gt=0, description="how far ahead the path is checked against new obstacles, m"
    )
    recoveries: list[Literal["clear_costmap", "spin", "wait", "back_up"]] = Field(
        default_factory=lambda: ["clear_costmap", "spin", "wait", "back_up"],
        description="tried in this order, one after each failed attempt at a goal",
    )
    spin_angle: float = Field(2 * math.pi, gt=0, description="the spin recovery's turn, rad")
    spin_rate: float = Field(1.0, gt=0, description="rad/s")
    wait_time: float = Field(5.0, gt=0, description="the wait recovery's pause, s")
    backup_distance: float = Field(0.15, gt=0, description="m")
    backup_speed: float = Field(0.05, gt=0, description="m/s")
    rotate_gain: float = Field(2.0, gt=0, description="P gain of the final in-place rotation")
