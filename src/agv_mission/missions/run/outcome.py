"""A run's outcome and record by its mission's :class:`Layout`, decided here alone.

A one-robot mission's run speaks in its robot's words and keeps its robot's record
(mission-format.md); a fleet's names the robot that failed and gathers every robot's
record with the fleet layer's log (fleet.md).
"""

from __future__ import annotations

from typing import Any

from agv_mission.missions.load.resolved import Layout
from agv_mission.missions.run.fleet_record import fleet_record
from agv_mission.missions.run.people_record import PeopleRun, fleet_people_metrics
from agv_mission.missions.run.record import RunRecord
from agv_mission.missions.run.robot_run import RobotRun


class RobotOutcome:
    """A one-robot mission (:attr:`Layout.ROBOT`): the robot's outcome is the run's."""

    def says(self, r: RobotRun, text: str) -> str:
        """``text`` about robot ``r`` as the run's reason."""
        return text

    def concluded(self, failed: RobotRun) -> tuple[str | None, str | None]:
        """The run's outcome once every robot ended, ``failed`` the first that did not
        succeed."""
        return failed.status, failed.reason

    def ended(self, lead: RobotRun, status: str, reason: str | None) -> tuple[str, str | None]:
        """The run's outcome when it is ended (``status``, ``reason``) after its robots
        were: the robot's own words stand (a fault fired)."""
        return lead.status or status, lead.reason

    def record(
        self,
        records: dict[str, RunRecord],
        outcome: tuple[str, str | None],
        people: PeopleRun | None,
        fleet_log: dict[str, Any],
        sim_time: float,
        wall_time: float,
        processes: int,
    ) -> RunRecord:
        """The run's record from its robots' (``records``, by name, in robot order)."""
        record = next(iter(records.values()))
        record.status, record.reason = outcome
        record.people = people.track if people is not None else None
        return record


class FleetOutcome(RobotOutcome):
    """A fleet mission (:attr:`Layout.FLEET`): every robot's record under ``robots``, the
    fleet layer's summary beside them."""

    def says(self, r: RobotRun, text: str) -> str:
        return f"{r.name}: {text}"

    def concluded(self, failed: RobotRun) -> tuple[str | None, str | None]:
        return "failed", self.says(failed, str(failed.reason))

    def ended(self, lead: RobotRun, status: str, reason: str | None) -> tuple[str, str | None]:
        return status, reason

    def record(
        self,
        records: dict[str, RunRecord],
        outcome: tuple[str, str | None],
        people: PeopleRun | None,
        fleet_log: dict[str, Any],
        sim_time: float,
        wall_time: float,
        processes: int,
    ) -> RunRecord:
        record = fleet_record(records, fleet_log, sim_time, wall_time, outcome, processes)
        if people is not None:
            record.people = people.track
            record.metrics["people"] = fleet_people_metrics(list(records.values()))
        return record


OUTCOMES: dict[Layout, RobotOutcome] = {Layout.ROBOT: RobotOutcome(), Layout.FLEET: FleetOutcome()}
