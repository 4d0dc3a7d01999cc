"""The configuration blocks of the built-in localisers (``stack.localization``).

Apart from the localisers, so that the schema needs none of their code (see
``planners/configs.py``).
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from agv_mission.registry import PluginConfig


class InitialPose(BaseModel):
    """amcl's ``initial_pose_x / _y / _a``."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    x: float
    y: float
    yaw: float = 0.0


#: Named parameter sets for ``profile``; keys given next to ``profile`` win.
PROFILES: dict[str, dict[str, Any]] = {
    "turtlebot3": {},  # the field defaults: TurtleBot3's amcl.launch
    "accurate": {"refine": True},
    "recovery": {
        "laser_model_type": "likelihood_field_prob",
        "laser_log_likelihood_scale": 0.1,
        "max_particles": 20000,
        "recovery_alpha_slow": 0.001,
        "recovery_alpha_fast": 0.1,
    },
}


class AmclConfig(PluginConfig):
    """ROS amcl's parameters, defaults from TurtleBot3's ``amcl.launch``."""

    plugin: ClassVar[str] = "agv_mission.localization.amcl:AmclLocalizer"

    type: Literal["amcl"] = "amcl"
    profile: Literal["accurate", "turtlebot3", "recovery"] = Field(
        "accurate",
        description="named defaults (PROFILES): accurate = amcl.launch's filter plus "
        "scan-to-map refinement (centimetre estimates with a consistent covariance); "
        "turtlebot3 = amcl.launch alone; recovery = global localisation and kidnap "
        "recovery; keys set next to it override it",
    )

    # Overall filter
    min_particles: int = Field(500, ge=1)
    max_particles: int = Field(3000, ge=1)
    kld_err: float = Field(0.02, gt=0)
    kld_z: float = Field(0.99, gt=0, description="used as the normal quantile, as amcl does")
    update_min_d: float = Field(0.2, ge=0, description="metres of motion between updates")
    update_min_a: float = Field(0.2, ge=0, description="radians of motion between updates")
    resample_interval: int = Field(1, ge=1)
    recovery_alpha_slow: float = Field(0.0, ge=0, le=1, description="0 disables; ROS: 0.001")
    recovery_alpha_fast: float = Field(0.0, ge=0, le=1, description="0 disables; ROS: 0.1")
    recovery_candidates: int = Field(
        50,
        ge=1,
        description="not in ROS: injected poses are drawn by the last scan's likelihood "
        "from this many uniform poses each (at most max_particles per update); 1 is "
        "amcl's uniform injection",
    )

    # Initial state
    initial_pose: InitialPose | None = Field(
        None, description="None: the mission's start pose (given to reset)"
    )
    initial_cov_xx: float = Field(0.25, ge=0, description="m^2")
    initial_cov_yy: float = Field(0.25, ge=0, description="m^2")
    initial_cov_aa: float = Field((math.pi / 12.0) ** 2, ge=0, description="rad^2")
    global_localization: bool = Field(
        False, description="start with max_particles spread over the free space"
    )

    # Laser model
    laser_model_type: Literal["likelihood_field", "likelihood_field_prob"] = "likelihood_field"
    laser_min_range: float = Field(-1.0, description="<= 0: the scan's range_min")
    laser_max_range: float = Field(3.5, description="<= 0: the scan's range_max")
    laser_max_beams: int = Field(180, ge=2)
    laser_z_hit: float = Field(0.5, ge=0)
    laser_z_rand: float = Field(0.5, ge=0)
    laser_sigma_hit: float = Field(0.2, gt=0)
    laser_likelihood_max_dist: float = Field(2.0, gt=0)
    laser_log_likelihood_scale: float = Field(
        1.0,
        gt=0,
        le=1,
        description="not in ROS: likelihood_field_prob multiplies each beam's log-likelihood "
        "by this; < 1 tempers the product of correlated beams (global localisation)",
    )

    # Odometry model (diff drive)
    odom_alpha1: float = Field(0.1, ge=0, description="rotation noise from rotation")
    odom_alpha2: float = Field(0.1, ge=0, description="rotation noise from translation")
    odom_alpha3: float = Field(0.1, ge=0, description="translation noise from translation")
    odom_alpha4: float = Field(0.1, ge=0, description="translation noise from rotation")

    # Scan-to-map refinement (not in ROS; see pose_tracker.PoseTracker)
    refine: bool = Field(
        False,
        description="refine the filter's estimate against the map's distance field with "
        "every scan (iterated EKF); the estimate and covariance then come from it",
    )
    refine_sigma: float = Field(0.02, gt=0, description="per-beam noise, m")
    refine_sigma_fraction: float = Field(
        0.0175,
        ge=0,
        description="per-beam noise as a fraction of the range where larger than refine_sigma "
        "(the LDS-01's 1.75 %); far beams count less and fit looser",
    )
    refine_max_innovation: float = Field(
        5.0,
        ge=0,
        description="Mahalanobis distance (prior covariance) beyond which a scan's correction "
        "is rejected as implausible given odometry; 0 disables",
    )
    refine_huber: float = Field(0.03, gt=0, description="robust kernel width, m")
    refine_outlier: float = Field(0.25, gt=0, description="beams farther off are ignored, m")
    refine_inlier: float = Field(0.05, gt=0, description="a beam this close fits, m")
    refine_min_inlier_fraction: float = Field(
        0.6, ge=0, le=1, description="fit-quality gate: share of beams that must fit"
    )
    refine_min_inlier_beams: int = Field(
        15,
        ge=3,
        description="or at least this many beams, and half the fraction, must fit (the others "
        "may see furniture the map lacks)",
    )
    refine_min_beams: int = Field(20, ge=3)
    refine_max_beams: int = Field(360, ge=3)
    refine_floor_xy: float = Field(
        0.003, gt=0, description="m: no single scan pins x or y tighter (beams correlate)"
    )
    refine_floor_yaw: float = Field(0.005, gt=0, description="rad: the same for yaw")
    refine_noise_along: float = Field(
        0.02, ge=0, description="odometry random walk: m sd after 1 m driven"
    )
    refine_noise_lateral: float = Field(0.01, ge=0, description="m sd sideways after 1 m")
    refine_noise_turn: float = Field(0.02, ge=0, description="rad sd after 1 rad turned")
    refine_noise_yaw_per_m: float = Field(0.01, ge=0, description="rad sd after 1 m driven")
    refine_map_error_scale: float = Field(
        1.0, ge=0, description="covariance floor: x, y sd = this times the fit's residual RMS"
    )
    refine_split_scale: float = Field(
        1.85,
        ge=0,
        description="> 0: the covariance floor is this times the pose spread implied by the "
        "disagreement of the scan's two halves (the map's own error where the robot is); "
        "0: refine_map_error_scale times the fit's residual RMS",
    )
    refine_map_error_lever: float = Field(
        2.0, gt=0, description="m: the yaw sd floor is the x, y floor over this"
    )
    refine_adaptive_noise: bool = Field(
        True, description="scale the odometry noise up when scans keep moving the prediction"
    )
    refine_max_failures: int = Field(
        25, ge=1, description="scans in a row that fail the gate before the filter takes over"
    )
    refine_start_std_xy: float = Field(
        0.15, gt=0, description="m: the filter must be this sure before refinement starts"
    )
    refine_jump: float = Field(
        0.5,
        gt=0,
        description="m (and rad, at least 0.3): a sure filter estimate this far from the "
        "tracked pose restarts the tracker there",
    )
    refine_filter_particles: int = Field(
        500,
        ge=1,
        description="while the refinement tracks, the particle filter (then the fallback and "
        "the jump check) resamples to at most this many particles instead of the KLD count",
    )
    refine_filter_beams: int = Field(
        30,
        ge=2,
        description="while the refinement tracks, the particle filter scores at most this "
        "many beams of each scan (ROS amcl's default laser_max_beams)",
    )

    # Plot support
    snapshot_interval: int = Field(5, ge=1, description="filter updates between snapshots")
    max_snapshots: int = Field(40, ge=2)

    @model_validator(mode="before")
    @classmethod
    def _profile_defaults(cls, data: Any) -> Any:
        """Fill the keys not given from the named profile (unknown names: the field's error)."""
        if isinstance(data, dict):
            name = data.get("profile", "accurate")
            preset = PROFILES.get(name) if isinstance(name, str) else None
            if preset:
                data = {**preset, **data}
        return data


class GroundTruthConfig(PluginConfig):
    """The estimate is the true pose."""

    plugin: ClassVar[str] = "agv_mission.localization.ground_truth:GroundTruthLocalizer"

    type: Literal["ground_truth"] = "ground_truth"


class OdometryConfig(PluginConfig):
    """map -> odom is fixed at the start; the estimate drifts with the encoders."""

    plugin: ClassVar[str] = "agv_mission.localization.odometry:OdometryLocalizer"

    type: Literal["odometry"] = "odometry"
