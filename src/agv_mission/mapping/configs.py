"""The configuration block of the built-in SLAM (``stack.slam``), apart from its code
(see ``planners/configs.py``)."""

from __future__ import annotations

import math
from typing import ClassVar, Literal

from pydantic import Field, model_validator

from agv_mission.registry import PluginConfig


class GridSlamConfig(PluginConfig):
    """Occupancy-grid SLAM parameters (the mission's ``stack.slam`` block)."""

    plugin: ClassVar[str] = "agv_mission.mapping.slam:GridSlam"

    type: Literal["grid"] = "grid"

    # Map
    resolution: float = Field(
        0.05, ge=0.001, le=1.0, description="metres per cell (a millimetre to a metre)"
    )
    map_margin: float = Field(
        1.0, ge=0, le=1000.0, description="metres allocated around the bounds"
    )
    initial_size: float = Field(
        20.0, gt=0, le=1000.0, description="side (m) of the square map allocated around the start"
    )
    grow_step: float = Field(
        2.0, gt=0, le=1000.0, description="metres added when a scan leaves the map"
    )
    log_odds_occupied: float = Field(0.85, gt=0, description="added per hit (p = 0.7)")
    log_odds_free: float = Field(-0.4, lt=0, description="added per pass-through (p = 0.4)")
    log_odds_min: float = Field(-2.0, lt=0)
    log_odds_max: float = Field(3.5, gt=0)
    occupied_threshold: float = Field(
        0.65, gt=0, lt=1, description="probability above which a cell is OCCUPIED"
    )
    free_threshold: float = Field(
        0.25, gt=0, lt=1, description="probability below which a cell is FREE"
    )
    max_range: float | None = Field(
        None, gt=0, description="returns beyond this (m) are not integrated; None: range_max"
    )
    missing_data_ray_length: float = Field(
        5.0,
        ge=0,
        description="m of free space a beam without a return (+inf) clears (Cartographer's "
        "missing_data_ray_length): not through doors and windows to the max range; 0: none",
    )
    free_max_hits: int | None = Field(
        None,
        ge=0,
        description="a cell that held more end points than this is never FREE, however often "
        "beams crossed it (a person walking by, a door that swung: no place a planner can "
        "trust); below hit_memory; None: the log-odds alone decide",
    )
    occupied_min_hits: int = Field(
        1,
        ge=1,
        description="a cell is OCCUPIED only once at least this many end points fell in it: "
        "one return at the end of a long beam through a door is no wall to trust (a person, "
        "a grazed edge, a beam's footprint 10 cm wide at 20 m); below hit_memory",
    )
    hit_memory: int = Field(
        20, ge=1, description="end points averaged per cell anchor (older ones fade out)"
    )
    wall_faces: bool = Field(
        False,
        description="draw a wall where its face is: an OCCUPIED cell whose end points lie "
        "beyond its centre, in front of another OCCUPIED cell, is not wall (the lidar's "
        "noise scattered the face's returns into it), nor UNKNOWN when free_max_hits is "
        "None and the log-odds left it undecided; agv-mission map's default. False (the "
        "mission SLAM's): every cell the log-odds make OCCUPIED (exploring map_area, a wall "
        "cell drawn FREE leaves frontiers at wall ends that are never cleared)",
    )
    update_min_d: float = Field(0.1, ge=0, description="metres of motion between integrations")
    update_min_a: float = Field(0.1, ge=0, description="radians of motion between integrations")

    # Scan matching
    match_min_d: float = Field(
        0.002, ge=0, description="metres of odometry motion before a scan is matched"
    )
    match_min_a: float = Field(
        0.002, ge=0, description="radians of odometry motion before a scan is matched"
    )
    linear_search_window: float = Field(0.2, ge=0, description="+- metres searched")
    angular_search_window: float = Field(
        math.radians(10.0), ge=0, description="+- radians searched"
    )
    angular_search_step: float | None = Field(
        None, gt=0, description="radians; None: one cell at the farthest point"
    )
    coarse_block: int = Field(4, ge=1, description="cells per coarse block (power of two)")
    translation_delta_cost_weight: float = Field(1.0, ge=0, description="1/m, search ties")
    rotation_delta_cost_weight: float = Field(1.0, ge=0, description="1/rad, search ties")
    likelihood_sigma: float = Field(0.05, gt=0, le=1.0, description="metres, field width")
    field_threshold: float = Field(
        0.0, description="log-odds above which a cell attracts scan points"
    )
    refinement: Literal["icp", "field", "none"] = Field(
        "icp", description="point-to-line (icp), bicubic field (hector) or none"
    )
    refine_iterations: int = Field(6, ge=0)
    point_sigma: float = Field(0.03, gt=0, le=1.0, description="m, std of a point-to-line residual")
    scan_sigma: float = Field(
        0.1, gt=0, le=10.0, description="std of a field residual (field mode)"
    )
    odom_prior: bool = Field(
        True, description="fuse the odometry prediction in the refinement (MAP estimate)"
    )
    odom_translation_noise: float = Field(
        0.05,
        ge=0,
        le=1.0,
        description="odometry prior: std (m) of the translation per metre driven",
    )
    odom_rotation_noise: float = Field(
        0.1, ge=0, le=1.0, description="odometry prior: std (rad) of the rotation per radian turned"
    )
    odom_rotation_per_metre: float = Field(
        0.2, ge=0, le=1.0, description="odometry prior: std (rad) of the rotation per metre driven"
    )
    odom_rotation_floor: float = Field(
        1e-3,
        ge=0,
        le=1.0,
        description="odometry prior: least std (rad) of the rotation between two matched "
        "scans (a gyro's is a tenth of the wheels': the runner sets it with the IMU on)",
    )
    match_max_range: float | None = Field(
        None, gt=0, description="points farther than this (m) are not matched; None: all"
    )
    search_max_range: float | None = Field(
        None,
        gt=0,
        description="m: only points this close (one per cell) are scored by the correlative "
        "search, the refinement uses all; None: all (a real lidar's 40 m returns make the "
        "search window and its angular steps huge)",
    )
    fast_match_score: float | None = Field(
        None,
        gt=0,
        le=1,
        description="when the refinement alone, from the odometry prediction, lands within "
        "a quarter of the window (fast_match_turn of heading) with at least this mean field "
        "value, the correlative search is skipped; None: always search",
    )
    fast_match_turn: float | None = Field(
        None,
        gt=0,
        description="rad: the search is skipped only when the refinement from the odometry "
        "prediction turned it by no more than this; None: a quarter of "
        "angular_search_window. A correction larger than the wheels' own heading error "
        "over the turn between two scans (3 % of a 45 deg turn: 0.025) is checked by the "
        "search rather than trusted",
    )
    odom_scale_std: float | None = Field(
        None,
        ge=1e-4,
        le=0.5,
        description="std of the odometry's scale error (a wheel radius off by a percent or "
        "two, Borenstein and Feng's UMBmark): learnt from the matches where the scan sees "
        "the motion, and the odometry's distances corrected by it; None: taken as exact",
    )
    match_gate: float | None = Field(
        None,
        gt=0,
        description="a match farther from the odometry prediction than this squared "
        "Mahalanobis distance (under the prediction's covariance plus the match's) is "
        "rejected: odometry only (16.3: 3 degrees of freedom at 0.1 %); None: no gate",
    )
    min_points: int = Field(20, ge=1, description="fewer valid points: odometry only")
    min_score: float = Field(
        0.1, ge=0, le=1, description="matches scoring below this are rejected (odometry only)"
    )

    @model_validator(mode="after")
    def _consistent(self) -> GridSlamConfig:
        """A cell cannot be both FREE and OCCUPIED; the coarse search halves its blocks."""
        if self.free_threshold >= self.occupied_threshold:
            raise ValueError("free_threshold must be below occupied_threshold")
        if self.coarse_block & (self.coarse_block - 1):
            raise ValueError("coarse_block must be a power of two")
        return self


class GraphSlamConfig(GridSlamConfig):
    """Grid SLAM with loop closure (the mission's ``stack.slam`` block, ``type: graph``)."""

    plugin: ClassVar[str] = "agv_mission.mapping.graph_slam:GraphSlam"

    type: Literal["graph"] = "graph"  # type: ignore[assignment]

    keyframe_distance: float = Field(0.3, gt=0, description="metres between keyframes")
    keyframe_angle: float = Field(0.35, gt=0, description="radians between keyframes")
    loop_check_every: int = Field(2, ge=1, description="keyframes between loop searches")
    loop_check_distance: float | None = Field(
        None,
        gt=0,
        description="metres driven between loop searches, whatever the keyframes; None: "
        "every loop_check_every keyframes only",
    )
    loop_min_travel: float = Field(
        8.0, gt=0, description="metres driven before a keyframe can close a loop"
    )
    loop_search_radius: float = Field(
        3.0, gt=0, description="candidates within this distance (m) of the estimate"
    )
    loop_linear_window: float = Field(1.0, gt=0, description="+- metres searched for a loop")
    loop_angular_window: float = Field(
        math.radians(20.0), gt=0, description="+- radians searched for a loop"
    )
    loop_min_score: float = Field(0.55, gt=0, le=1, description="mean field value to accept")
    loop_submap_keyframes: int = Field(12, ge=1, description="keyframes each side in a submap")
    odom_edge_sigma: tuple[float, float] = Field(
        (0.01, 0.005),
        description="m, rad per metre / radian of motion: the least std of a keyframe-to-"
        "keyframe edge, on top of the front end's match covariance",
    )
    loop_edge_sigma: tuple[float, float] = Field(
        (0.05, 0.05), description="m, rad: std of a loop edge"
    )
    loop_consistent: float = Field(
        0.02,
        ge=0,
        description="m / rad: a loop edge closer than this to the graph is kept without a solve",
    )
    loop_search_growth: float = Field(
        0.0,
        ge=0,
        description="m of loop search radius (and window) added per metre driven since the "
        "last loop closure: the drift a scan matcher's heading error of a few tenths of a "
        "degree per metre builds up (the ACES log: 7 m after 250 m; agv-mission map's "
        "long-range default 0.03); 0: a fixed search. A short-range lidar's scan (3.5 m) "
        "is too small to be placed alone over metres: on the house patrol's bag a wide "
        "search took a worse closure (free-cell IoU 0.952 -> 0.947)",
    )
    loop_max_radius: float = Field(
        8.0, gt=0, description="m: the widest loop search, however long since the last closure"
    )
    loop_wide_angular_window: float = Field(
        math.radians(30.0),
        gt=0,
        description="+- radians searched for a loop when the radius has grown beyond "
        "loop_search_radius",
    )
    loop_verify: tuple[float, float] = Field(
        (0.3, 0.05),
        description="m, rad: a loop closure that moves the graph by more waits for a second "
        "one nearby that agrees with it before either enters the graph",
    )
    loop_pair_travel: float = Field(
        30.0, gt=0, description="m driven within which two loop closures can confirm each other"
    )
    loop_pair_tolerance: tuple[float, float] = Field(
        (0.3, 0.05),
        description="m, rad: how far two loop closures may disagree and still confirm each "
        "other (plus 1 % / 0.002 rad per metre of graph between their ends)",
    )
    loop_gate: float = Field(
        5.0,
        gt=0,
        description="whitened residual of a loop edge the solved graph cannot satisfy: "
        "that edge is dropped and the graph solved again",
    )
    final_smoothing: bool = Field(
        False,
        description="offline (agv-mission map), once the recording ends: the trajectory "
        "smoothed with the odometry and the map rendered again from it",
    )
    smoothing_sigma: tuple[float, float] = Field(
        (0.02, 0.01),
        description="m, rad: std of a front-end pose in the final smoothing (the 2 cm / "
        "0.6 deg relative pose error the scan-to-map front end alone makes over 1 m on the "
        "Freiburg 079 log)",
    )
    smoothing_calibration: bool = Field(
        False,
        description="the final smoothing learns the odometry's systematic errors (scale, "
        "heading drift per metre driven and per radian turned: unequal wheel diameters, a "
        "wheelbase off) from the whole trajectory and takes them out of its motion first",
    )
    final_odometry_edges: bool = Field(
        False,
        description="offline, before the final smoothing: the pose graph solved again with "
        "the odometry's motion between consecutive keyframes as edges of their own "
        "(calibrated as for smoothing_calibration, noise smoothing_odom_noise, its heading "
        "noise widened when this recording's wheels slip more than that) and the front "
        "end's edges between them widened to their real spread",
    )
    smoothing_odom_noise: tuple[float, float, float] | None = Field(
        None,
        description="m per metre, rad per radian, rad per metre: std of the odometry's "
        "random error in the final smoothing (Thrun's odometry motion model); None: the "
        "front end's odometry prior (odom_translation_noise, odom_rotation_noise, "
        "odom_rotation_per_metre)",
    )
    rebuild_threshold: float = Field(
        0.05,
        ge=0,
        description="the map is rebuilt when a keyframe moved more (m); less than a cell "
        "is not worth re-integrating every scan",
    )
    rebuild_now_threshold: float = Field(
        0.1,
        ge=0,
        description="moved more (m): rebuild at once for the front end; less: when the "
        "map is next asked for",
    )
