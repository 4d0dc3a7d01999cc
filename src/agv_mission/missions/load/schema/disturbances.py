"""What the world does to the robot beyond its map: unmapped ``obstacles`` and injected
``faults``."""

from __future__ import annotations

from typing import Annotated, Literal, Union

from pydantic import Field, model_validator

from agv_mission.missions.load.schema.base import Pose, StrictModel


class BoxObstacle(StrictModel):
    """An unmapped box: present in the simulation, absent from the robot's map."""

    type: Literal["box"]
    x: float
    y: float
    size_x: float = Field(gt=0, description="full length along its own x, m")
    size_y: float = Field(gt=0, description="full width along its own y, m")
    yaw: float = 0.0


class CylinderObstacle(StrictModel):
    """An unmapped cylinder (a person, a bin): in the simulation, not on the map."""

    type: Literal["cylinder"]
    x: float
    y: float
    radius: float = Field(gt=0)


Obstacle = Annotated[Union[BoxObstacle, CylinderObstacle], Field(discriminator="type")]  # noqa: UP007


class Aimed(StrictModel):
    """A fault of a fleet mission hits one robot (``robot``) or every robot (unset)."""

    robot: str | None = Field(
        None, description="the fleet robot it hits (unset: every robot); a kidnap names one"
    )


class Window(Aimed):
    start: float = Field(0.0, ge=0.0, description="simulated seconds")
    end: float | None = Field(None, gt=0.0, description="simulated seconds; None: to the end")

    @model_validator(mode="after")
    def _ordered(self) -> Window:
        if self.end is not None and self.end <= self.start:
            raise ValueError(f"end ({self.end:g}) must come after start ({self.start:g})")
        return self


class LidarDropoutFault(Window):
    """Scans are lost with probability ``rate`` inside the window."""

    type: Literal["lidar_dropout"]
    rate: float = Field(1.0, gt=0.0, le=1.0)


class WheelSlipFault(Window):
    """The wheels slip: each encoder read is off by up to ``factor`` of the travel."""

    type: Literal["wheel_slip"]
    factor: float = Field(gt=0.0, le=1.0)


class OdometryNoiseFault(Window):
    """Encoder noise multiplied by ``scale`` (added as ``0.01 * scale`` when it is off)."""

    type: Literal["odometry_noise"]
    scale: float = Field(gt=0.0)


class KidnapFault(Aimed):
    """The robot is carried to ``pose`` at ``time`` (the localiser is not told)."""

    type: Literal["kidnap"]
    time: float = Field(gt=0.0, description="simulated seconds")
    pose: Pose


Fault = Annotated[
    Union[LidarDropoutFault, WheelSlipFault, OdometryNoiseFault, KidnapFault],  # noqa: UP007
    Field(discriminator="type"),
]
