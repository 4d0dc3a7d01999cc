"""Which vehicles a mission file makes, and running them until stopped.

A one-robot mission is one vehicle, serial number ``agv1`` (its ``robot:`` names a model,
not an individual). A mission with a ``robots:`` list (``fleet.md``) is one vehicle per
robot, serial number its ``name``, every robot a body of the mission's one world (their
lidars see each other, their contacts count): one :class:`~agv_mission.vda5050.body.
VehicleWorld`. ``tasks`` are ignored: a vehicle does what its orders say.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from agv_mission.missions.load.resolved import Layout, LoadedMission
from agv_mission.robots.description import RobotDescription
from agv_mission.vda5050.body import VehicleWorld
from agv_mission.vda5050.dispatch_mission import load_dispatch_mission
from agv_mission.vda5050.transport import BrokerUrl
from agv_mission.vda5050.vehicle import Vehicle

DEFAULT_SERIAL = "agv1"


@dataclass(frozen=True)
class VehicleSpec:
    """One vehicle: its serial number and the robot of the mission it drives."""

    serial: str
    robot: str  # the robot's name in the run
    description: RobotDescription


@dataclass(frozen=True)
class VehicleMission:
    """A mission file's world and the vehicles its robots are."""

    loaded: LoadedMission
    vehicles: list[VehicleSpec]


def load_vehicles(
    path: Path, overrides: list[str] | None = None, seed: int | None = None
) -> VehicleMission:
    """The vehicles of mission file ``path`` (its tasks' ``actions:`` ignored). Raises
    :class:`MissionError` (exit code 2)."""
    loaded = load_dispatch_mission(
        path, overrides, seed, tasks_required=False, check_actions=False
    ).loaded
    sole = loaded.layout is Layout.ROBOT  # a one-robot mission's vehicle: the default serial
    return VehicleMission(
        loaded,
        [VehicleSpec(DEFAULT_SERIAL if sole else r.name, r.name, r.robot) for r in loaded.robots],
    )


class VehicleSet:
    """A mission's world and its vehicles, started and stopped together."""

    def __init__(
        self,
        mission: VehicleMission,
        broker: BrokerUrl,
        manufacturer: str = "agv-mission",
        time_scale: float = 1.0,
        log_dir: Path | None = None,
    ) -> None:
        self.world = VehicleWorld(mission.loaded, time_scale)
        self.vehicles: list[Vehicle] = []
        for spec in mission.vehicles:
            body = self.world.bodies[spec.robot]
            vehicle = Vehicle(body, spec.description, broker, spec.serial, manufacturer, log_dir)
            body.on_change = vehicle.wake
            self.vehicles.append(vehicle)

    def start(self, timeout: float = 120.0) -> None:
        """The world first (its set-up takes a while), then the MQTT side."""
        self.world.start()
        if not self.world.ready.wait(timeout) or self.world.error:
            raise RuntimeError(f"the simulation did not start: {self.world.error}")
        for vehicle in self.vehicles:
            vehicle.start()

    def failed(self) -> str | None:
        """Why the world stopped on its own, if it did."""
        record = self.world.record
        if record is not None and record.status != "aborted":
            return f"the simulation ended ({record.status}): {record.reason}"
        return None

    def stop(self) -> None:
        for vehicle in self.vehicles:
            vehicle.stop()
        self.world.stop()
