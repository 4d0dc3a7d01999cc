"""The robot's battery: a level drained by a motion power model and an idle load, raised
by a charger while docked. Simulated time only.

The motion model follows Open-RMF's ``rmf_battery`` ``SimpleMotionPowerSink`` (our own
code): the power the wheels deliver is what accelerates the robot's mass and yaw inertia
plus what rolling friction takes, ``m a v + I alpha w + mu m g |wheel speed|``; braking
gives nothing back (no regeneration), and the motors and gears turn only
``drive_efficiency`` of the battery's power into it. The electronics draw ``idle_power``
all the time. A charger, while the robot is docked, supplies the idle load and raises the
level at ``charge_power``.

:class:`Battery.step` runs once per control step in the run's hot loop: plain float
arithmetic, a few microseconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pydantic import BaseModel, ConfigDict, Field

GRAVITY = 9.81  # m/s^2
WH = 3600.0  # joules per watt-hour


class BatterySpec(BaseModel):
    """A robot's battery and the power its drive and electronics draw from it."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, defer_build=True)

    capacity: float = Field(..., gt=0, le=1e6, description="usable energy, Wh")
    initial_level: float = Field(1.0, ge=0, le=1, description="state of charge at the start")
    idle_power: float = Field(
        ..., ge=0, le=1e5, description="W drawn standing still (computer, lidar, boards)"
    )
    charge_power: float = Field(..., gt=0, le=1e5, description="W into the battery when docked")
    voltage: float | None = Field(
        None, gt=0, le=1e4, description="nominal V (for /battery_state's charge in Ah)"
    )
    rolling_resistance: float = Field(
        0.03, ge=0, le=1, description="rolling friction coefficient of the wheels on the floor"
    )
    drive_efficiency: float = Field(
        0.5, gt=0, le=1, description="share of the battery's drive power that reaches the wheels"
    )


@dataclass
class Battery:
    """The state of charge of one robot during a run.

    ``mass`` (kg), ``inertia`` (kg m^2, about the yaw axis) and ``track`` (wheel
    separation, m) are the robot's; ``level`` is 0..1 of ``spec.capacity``.
    """

    spec: BatterySpec
    mass: float
    inertia: float
    track: float
    level: float = math.nan
    charging: bool = False  # set by a Charge behaviour while the robot is docked
    energy_used: float = 0.0  # J drawn (idle load and motion)
    energy_charged: float = 0.0  # J put in by the charger
    charging_time: float = 0.0  # s spent charging
    minimum: float = math.nan
    start: float = field(init=False)
    _v: float = 0.0
    _w: float = 0.0

    def __post_init__(self) -> None:
        if math.isnan(self.level):
            self.level = self.spec.initial_level
        self.start = self.minimum = self.level
        self._capacity_j = self.spec.capacity * WH
        self._friction = self.spec.rolling_resistance * self.mass * GRAVITY
        self._half_track = self.track / 2.0

    @property
    def empty(self) -> bool:
        return self.level <= 0.0

    def motion_power(self, v: float, w: float, dt: float) -> float:
        """W the drive draws from the battery to go at (v, w) for ``dt`` after (v0, w0)."""
        a = (v - self._v) / dt
        alpha = (w - self._w) / dt
        # the two wheels' mean speed: |v| driving straight, |w| b/2 turning in place
        wheels = max(abs(v), abs(w) * self._half_track)
        mechanical = (
            max(self.mass * a * v, 0.0)
            + max(self.inertia * alpha * w, 0.0)
            + self._friction * wheels
        )
        return mechanical / self.spec.drive_efficiency

    def step(self, v: float, w: float, dt: float) -> float:
        """Integrate ``dt`` seconds at the commanded (v, w); returns the new level."""
        spec = self.spec
        if self.charging:
            gained = spec.charge_power * dt
            self.energy_charged += gained
            self.charging_time += dt
            drawn = self.motion_power(v, w, dt) * dt
            self.level = min(1.0, self.level + (gained - drawn) / self._capacity_j)
        else:
            drawn = (spec.idle_power + self.motion_power(v, w, dt)) * dt
            self.level = max(0.0, self.level - drawn / self._capacity_j)
        self.energy_used += drawn
        self._v, self._w = v, w
        if self.level < self.minimum:
            self.minimum = self.level
        return self.level

    def report(self) -> dict[str, float]:
        """``metrics.battery`` of result.json: levels 0..1, energy in Wh, time in s."""
        return {
            "capacity": round(self.spec.capacity, 4),
            "start": round(self.start, 6),
            "end": round(self.level, 6),
            "minimum": round(self.minimum, 6),
            "energy_used": round(self.energy_used / WH, 6),
            "energy_charged": round(self.energy_charged / WH, 6),
            "charging_time": round(self.charging_time, 3),
        }


def battery_for(
    spec: BatterySpec,
    mass: float,
    footprint_radius: float,
    track: float,
    level: float | None = None,
) -> Battery:
    """A robot's battery at ``level`` (default: the spec's initial level); the robot's yaw
    inertia is a uniform disc's, m r^2 / 2."""
    inertia = 0.5 * mass * footprint_radius**2
    return Battery(spec, mass, inertia, track, spec.initial_level if level is None else level)
