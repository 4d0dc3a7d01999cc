"""The mission's ``simulation:`` block, apart from the simulator so that validating a
mission does not import MuJoCo."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator


class SimConfig(BaseModel):
    """Simulation settings: physics rate and the sensors' errors.

    The sensors' errors default to the robot's own (its ``encoder`` and ``lidar`` specs,
    the real sensors' figures for the built-in robots); a key set here overrides the
    robot's value, and ``ideal: true`` turns every error off (perfect encoders apart from
    their ticks, a noise-free lidar that never drops a beam).
    """

    model_config = ConfigDict(extra="forbid", defer_build=True)

    physics_dt: float = Field(0.01, gt=0, le=0.02, description="physics time step, s")
    ideal: bool = Field(
        False,
        description="perfect sensors: no encoder noise, slip or scale error, no lidar noise "
        "or dropouts (keys set next to it still apply)",
    )
    encoder_noise: float | None = Field(
        None,
        ge=0,
        description="std of the relative tick error of each encoder read (None: the robot's)",
    )
    wheel_slip: float | None = Field(
        None,
        ge=0,
        le=1,
        description="each read's wheel travel is scaled by 1 + U(-slip, slip) (None: the robot's)",
    )
    wheel_scale_error: float | None = Field(
        None,
        ge=0,
        le=0.1,
        description="std of each wheel's systematic scale error, drawn once per run from the "
        "seed (None: the robot's)",
    )
    lidar_noise: float | None = Field(
        None, ge=0, description="range noise std at short range, m (None: the robot's)"
    )
    lidar_noise_fraction: float | None = Field(
        None,
        ge=0,
        le=0.5,
        description="range noise std as a fraction of the range, where that is larger than "
        "lidar_noise (None: the robot's)",
    )
    lidar_dropout: float | None = Field(
        None,
        ge=0,
        le=1,
        description="probability that a beam returns nothing (None: the robot's)",
    )

    battery_level: float | None = Field(
        None,
        ge=0,
        le=1,
        description="the battery's level at the start, 0..1 (None: the robot's initial_level)",
    )

    processes: int | Literal["auto"] = Field(
        "auto",
        description="processes a fleet's robots decide in (each robot in one; the world is "
        "stepped in each): auto is one per core, up to one per robot, in a run started from "
        "the command line; 1 decides every robot in one process. The outcome is the same "
        "for any value: it only changes how fast a fleet runs",
    )

    @field_validator("processes")
    @classmethod
    def _positive(cls, value: int | str) -> int | str:
        if isinstance(value, int) and value < 1:
            raise ValueError("processes must be 'auto' or at least 1")
        return value

    def pick(self, key: str, robot_value: float) -> float:
        """The value of sensor error ``key``: set here, else 0 when ideal, else the robot's."""
        value = getattr(self, key)
        if value is not None:
            return float(value)
        return 0.0 if self.ideal else float(robot_value)
