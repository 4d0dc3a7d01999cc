"""The costmap's configuration (the mission's ``stack.costmap`` block).

Apart from :mod:`agv_mission.maps.costmap` so that the mission schema, which validating a
file or printing ``--help`` needs, imports no distance transform (scipy).
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ObstacleLayerConfig(BaseModel):
    """Marking and clearing (the mission's ``stack.costmap.obstacles`` block)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    enabled: bool = True
    max_range: float = Field(2.5, gt=0, description="returns farther than this do not mark, m")
    raytrace_range: float = Field(3.0, gt=0, description="beams clear up to this range, m")
    map_tolerance: float = Field(
        0.15, ge=0, description="returns this close to a mapped obstacle are the map's, m"
    )


class CostmapConfig(BaseModel):
    """Costmap parameters (the mission's ``stack.costmap`` block)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)

    resolution: float | None = Field(
        None,
        gt=0,
        description="metres per cell; default: the map's own. The map is resampled, each "
        "cell taking the worst of the map cells it covers (occupied > unknown > free)",
    )
    inflation_radius: float = Field(0.3, ge=0, description="metres beyond the footprint")
    cost_scaling_factor: float = Field(5.0, gt=0, description="exponential decay of cost")
    unknown_is_obstacle: bool = True
    obstacles: ObstacleLayerConfig = Field(
        default_factory=ObstacleLayerConfig,
        description="the lidar's obstacle layer over the static map",
    )
