"""The ``expect:`` block of a mission file: what a scenario expects of its run.

``agv-mission run`` ignores the block; ``agv-mission regress`` checks a run's result
against it (:func:`agv_mission.missions.report.expectations.check`). Every key is
optional; a scenario without ``expect:`` is expected to succeed (see
:data:`DEFAULT_EXPECTATIONS`).
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

RunStatus = Literal["succeeded", "failed", "aborted", "error"]
TaskStatus = Literal["succeeded", "partial", "skipped", "failed", "aborted", "not_run", "running"]


class Expectations(BaseModel):
    """Bounds on one run's result; every key optional, unknown keys are invalid."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    status: RunStatus | None = Field(None, description="final status of the mission")
    reason_contains: str | None = Field(
        None, description="text the failure reason must contain (for expected failures)"
    )
    tasks: list[TaskStatus | None] | dict[int, TaskStatus] | None = Field(
        None,
        description="per-task status: a list in task order (null skips a task) or a mapping "
        "from the 1-based task index to its status",
    )
    sim_time_max: float | None = Field(None, ge=0.0, description="simulated seconds, at most")
    sim_time_min: float | None = Field(
        None, ge=0.0, description="simulated seconds, at least (a shift that must last)"
    )
    collisions_max: int | None = Field(None, ge=0, description="collisions, at most")
    min_clearance_min: float | None = Field(
        None, description="metres between the robot's footprint and obstacles, at least"
    )
    distance_driven_max: float | None = Field(None, ge=0.0, description="metres, at most")
    keepout_time_max: float | None = Field(
        None,
        ge=0.0,
        description="seconds the footprint overlapped a keepout zone (metrics.zones), at most; "
        "for a robot started inside one, how long it took to leave",
    )
    keepout_time_after_exit_max: float | None = Field(
        None, ge=0.0, description="seconds back inside a keepout zone once out of it, at most"
    )
    speed_violation_time_max: float | None = Field(
        None,
        ge=0.0,
        description="seconds above a speed zone's limit by more than 5 % (metrics.zones), at most",
    )
    speed_ratio_max: float | None = Field(
        None, ge=0.0, description="highest true speed / limit inside speed zones, at most"
    )
    people_collisions_max: int | None = Field(
        None, ge=0, description="contacts begun with a person (metrics.people.collisions), at most"
    )
    people_min_distance_min: float | None = Field(
        None,
        description="metres from the robot's footprint to the nearest person's edge over the "
        "run (metrics.people.min_distance), at least",
    )
    personal_time_max: float | None = Field(
        None,
        ge=0.0,
        description="seconds with a person closer than 1.2 m to the footprint "
        "(metrics.people.personal_time), at most",
    )
    not_moving_share_max: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="share of the run the robot stood among people (metrics.people."
        "time_not_moving / sim_time), at most",
    )
    driven_vs_shortest_max: float | None = Field(
        None,
        ge=1.0,
        description="on every leg that succeeded, distance driven / the shortest path between "
        "its start and goal at the planner's clearance (metrics.navigation.legs), at most",
    )
    driven_vs_planned_max: float | None = Field(
        None, ge=0.0, description="on every leg that succeeded, driven / first plan's length"
    )
    planned_vs_shortest_max: float | None = Field(
        None, ge=1.0, description="on every leg that succeeded, first plan's length / shortest"
    )
    driven_vs_shortest_free_max: float | None = Field(
        None,
        ge=1.0,
        description="on every leg that succeeded, distance driven / the shortest free path "
        "(any-angle, in the robot's configuration space; metrics.navigation.legs), at most",
    )
    planned_vs_shortest_free_max: float | None = Field(
        None, ge=1.0, description="on every leg that succeeded, first plan's length / shortest free"
    )
    stops_max: int | None = Field(
        None,
        ge=0,
        description="stop-and-go events (moving, standing, moving again) within legs, at most",
    )
    localization_rmse_max: float | None = Field(
        None, ge=0.0, description="position RMSE of the estimate against ground truth, metres"
    )
    localization_max_error_max: float | None = Field(
        None,
        ge=0.0,
        description="largest position error of the estimate against ground truth, metres "
        "(a run that loses its localisation misses it)",
    )
    localization_consistency_min: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="share of steps whose true error lies within the reported covariance's "
        "2-sigma ellipse, at least",
    )
    map_iou_min: float | None = Field(
        None,
        ge=0.0,
        le=1.0,
        description="free-space intersection over union of every built map with the true "
        "map (result.json maps[i].free_iou), at least",
    )
    map_occupied_iou_min: float | None = Field(
        None, ge=0.0, le=1.0, description="occupied-cell IoU of every built map, at least"
    )
    map_coverage_min: float | None = Field(
        None, ge=0.0, le=1.0, description="share of the reachable free space mapped, at least"
    )
    rooms_recorded: list[str] | None = Field(
        None, description="room labels that must have been recorded"
    )
    waypoints_reached: int | None = Field(
        None, ge=0, description="patrol waypoints reached over all patrol tasks and loops, at least"
    )
    battery_min_min: float | None = Field(
        None, ge=0.0, le=1.0, description="lowest battery level of the run (0..1), at least"
    )
    battery_end_min: float | None = Field(
        None, ge=0.0, le=1.0, description="battery level at the end (0..1), at least"
    )
    battery_energy_used_max: float | None = Field(
        None, ge=0.0, description="energy drawn from the battery, Wh, at most"
    )
    dockings_min: int | None = Field(None, ge=0, description="times the robot docked, at least")
    nodes: dict[str, Literal["succeeded", "failed", "running", "not_run"]] | None = Field(
        None,
        description="final status of tree nodes, by name or path (result.json `tree`); a "
        "name several nodes share must hold for each",
    )
    # fleets (fleet.md): the fleet's summary, result.json `fleet`
    robot_robot_collisions_max: int | None = Field(
        None, ge=0, description="contacts between two robots, at most"
    )
    robot_robot_min_distance_min: float | None = Field(
        None, description="metres between the closest two robots' bodies over the run, at least"
    )
    makespan_max: float | None = Field(
        None, ge=0.0, description="simulated seconds until every robot's part ended, at most"
    )
    deadlocks_max: int | None = Field(
        None, ge=0, description="deadlocks the traffic layer had to break, at most"
    )
    robots: dict[str, Expectations] | None = Field(
        None,
        description="per robot of a fleet, by name: the one-robot keys, checked against "
        "result.json `robots.NAME`",
    )


Expectations.model_rebuild()
DEFAULT_EXPECTATIONS = Expectations(status="succeeded")
