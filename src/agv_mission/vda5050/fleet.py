"""Which vehicles a mission file makes, and running them until stopped.

A one-robot mission is one vehicle, serial number ``agv1`` (its ``robot:`` names a model,
not an individual). A mission with a ``robots:`` list (``fleet.md``) is one vehicle per
robot, serial number its ``name``; until the fleet world exists each robot runs in a world
of its own, on a thread of its own, in this one process (a stop-gap: their lidars do not
see each other). ``tasks`` are ignored: a vehicle does what its orders say.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from agv_mission.missions.errors import MissionError, Problem
from agv_mission.missions.loader import LoadedMission, load_mission
from agv_mission.vda5050.body import SimulatedBody
from agv_mission.vda5050.transport import BrokerUrl
from agv_mission.vda5050.vehicle import Vehicle

DEFAULT_SERIAL = "agv1"
FLEET_KEYS = ("robots", "tasks", "fleet", "expect", "tree")


@dataclass(frozen=True)
class VehicleSpec:
    serial: str
    loaded: LoadedMission


def load_vehicles(
    path: Path, overrides: list[str] | None = None, seed: int | None = None
) -> list[VehicleSpec]:
    """The vehicles of mission file ``path``. Raises :class:`MissionError` (exit code 2)."""
    try:
        text = path.read_text(encoding="utf-8")
        doc = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise MissionError(
            [Problem(str(path), None, "", f"cannot read the mission: {exc}")]
        ) from None
    if not isinstance(doc, dict) or "robots" not in doc:
        tasks = doc.get("tasks") if isinstance(doc, dict) else None
        if isinstance(tasks, list) and any(isinstance(t, dict) and "actions" in t for t in tasks):
            # the master's node actions (``dispatch`` only): not the vehicle's business
            doc["tasks"] = [
                {k: v for k, v in t.items() if k != "actions"} if isinstance(t, dict) else t
                for t in tasks
            ]
            text = yaml.safe_dump(doc, sort_keys=False)
            loaded = load_mission(path, overrides, seed, text=text, tasks_required=False)
        else:
            loaded = load_mission(path, overrides, seed, tasks_required=False)
        return [VehicleSpec(DEFAULT_SERIAL, loaded)]
    robots = doc["robots"]
    if not isinstance(robots, list) or not robots:
        raise MissionError([Problem(str(path), None, "robots", "a non-empty list of robots")])
    base = {k: v for k, v in doc.items() if k not in FLEET_KEYS}
    specs: list[VehicleSpec] = []
    for i, robot in enumerate(robots):
        if not isinstance(robot, dict) or not isinstance(robot.get("name"), str):
            raise MissionError([Problem(str(path), None, f"robots.{i}", "each robot needs a name")])
        one: dict[str, Any] = copy.deepcopy(base)
        one["name"] = f"{doc.get('name', path.stem)}-{robot['name']}"
        for key in ("robot", "start"):
            if key in robot:
                one[key] = robot[key]
        if isinstance(robot.get("stack"), dict):
            one["stack"] = {**one.get("stack", {}), **robot["stack"]}
        text_one = yaml.safe_dump(one, sort_keys=False)
        try:
            loaded = load_mission(path, overrides, seed, text=text_one, tasks_required=False)
        except MissionError as exc:
            raise MissionError(
                [
                    Problem(p.file, None, f"robots.{i}.{p.field}".rstrip("."), p.message)
                    for p in exc.problems
                ]
            ) from None
        specs.append(VehicleSpec(robot["name"], loaded))
    return specs


class VehicleSet:
    """Bodies and vehicles of a mission file, started and stopped together."""

    def __init__(
        self,
        specs: list[VehicleSpec],
        broker: BrokerUrl,
        manufacturer: str = "agv-mission",
        time_scale: float = 1.0,
        log_dir: Path | None = None,
    ) -> None:
        self.bodies: list[SimulatedBody] = []
        self.vehicles: list[Vehicle] = []
        for spec in specs:
            body = SimulatedBody(spec.loaded, time_scale)
            vehicle = Vehicle(body, spec.loaded.robot, broker, spec.serial, manufacturer, log_dir)
            body.on_change = vehicle.wake
            self.bodies.append(body)
            self.vehicles.append(vehicle)

    def start(self, timeout: float = 120.0) -> None:
        """Bodies first (their set-up takes a while), then the MQTT side."""
        for body in self.bodies:
            body.start()
        for body in self.bodies:
            if not body.ready.wait(timeout) or body.error:
                raise RuntimeError(f"{body.robot_name}: the simulation did not start: {body.error}")
        for vehicle in self.vehicles:
            vehicle.start()

    def failed(self) -> str | None:
        """Why a body stopped on its own, if one did."""
        for vehicle, body in zip(self.vehicles, self.bodies, strict=True):
            if body.record is not None and body.record.status != "aborted":
                return f"{vehicle.serial}: the simulation ended: {body.record.reason}"
        return None

    def stop(self) -> None:
        for vehicle in self.vehicles:
            vehicle.stop()
        for body in self.bodies:
            body.stop()
