"""The mission's ``simulation:`` block, apart from the simulator so that validating a
mission does not import MuJoCo."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class SimConfig(BaseModel):
    """Simulation settings (physics rate and sensor faults)."""

    model_config = ConfigDict(extra="forbid")

    physics_dt: float = Field(0.01, gt=0, le=0.02, description="physics time step, s")
    encoder_noise: float = Field(
        0.0, ge=0, description="std of the relative tick error of each encoder read"
    )
    wheel_slip: float = Field(
        0.0,
        ge=0,
        le=1,
        description="each read's wheel travel is scaled by 1 + U(-slip, slip) (encoder error)",
    )
    lidar_noise: float | None = Field(
        None, ge=0, description="range noise std override, m (None: the robot's LidarSpec)"
    )
    battery_level: float | None = Field(
        None,
        ge=0,
        le=1,
        description="the battery's level at the start, 0..1 (None: the robot's initial_level)",
    )
