"""The ``stack`` block: one plugin per slot, chosen by ``type``.

Each slot is a union of the ``Config`` models of every plugin registered for it, told
apart by ``type``; a new plugin extends the schema by registering itself.
"""

from __future__ import annotations

from typing import Annotated, Any, Union

from pydantic import Field

from agv_mission.maps.costmap_config import CostmapConfig
from agv_mission.missions.load.schema.base import StrictModel
from agv_mission.navigation.config import NavigationConfig
from agv_mission.planners.collision_monitor import CollisionMonitorConfig
from agv_mission.registry import registry


def _plugin_union(slot: str) -> Any:
    """A discriminated union of the config models of every plugin of ``slot``."""
    configs = tuple(registry.configs(slot))
    if len(configs) == 1:
        return configs[0]
    return Annotated[Union[configs], Field(discriminator="type")]  # noqa: UP007


LocalizationConfig = _plugin_union("localization")
GlobalPlannerConfig = _plugin_union("global_planner")
LocalPlannerConfig = _plugin_union("local_planner")
SlamConfig = _plugin_union("slam")


# The plugin a stack block without ``type`` (or no block at all) selects.
DEFAULT_PLUGINS = {
    "localization": "amcl",
    "global_planner": "cost_grid",
    "local_planner": "mpc",
    "slam": "grid",
}


def with_default_plugin_types(data: Any) -> Any:
    """``data`` with ``type`` filled in for every stack block that leaves it out (in place),
    so ``--set stack.global_planner.planner=RRTstar`` works without a block in the file.

    A block is the slot's default plugin, unless its keys are not all the default's and
    exactly one plugin of the slot has them all (``planner`` is OMPL's alone)."""
    stack = data.get("stack") if isinstance(data, dict) else None
    if isinstance(stack, dict):
        for slot, name in DEFAULT_PLUGINS.items():
            block = stack.get(slot)
            if isinstance(block, dict) and "type" not in block:
                block["type"] = _plugin_with_keys(slot, set(block)) or name
    return data


def _plugin_with_keys(slot: str, keys: set[Any]) -> str | None:
    """The one plugin of ``slot`` whose config has every key of ``keys`` when the default
    plugin's does not; None otherwise."""
    configs = {
        config.model_fields["type"].default: set(config.model_fields)
        for config in registry.configs(slot)
    }
    if keys <= configs.get(DEFAULT_PLUGINS[slot], set()):
        return None
    fits = [name for name, fields in configs.items() if keys <= fields]
    return fits[0] if len(fits) == 1 else None


def _default(slot: str, name: str) -> Any:
    return registry.config(slot, name)()


class OdometrySource(StrictModel):
    """What the odometry (``/odom``, the localiser's motion) is made of."""

    imu: bool = Field(
        True,
        description="fuse the IMU's gyro with the wheels, as robot_localization's EKF on a "
        "TurtleBot3 or Jackal; false: the wheels alone (a robot without an IMU always)",
    )


class Stack(StrictModel):
    """The navigation stack: one plugin per slot, chosen by ``type``."""

    localization: LocalizationConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("localization", DEFAULT_PLUGINS["localization"])
    )
    global_planner: GlobalPlannerConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("global_planner", DEFAULT_PLUGINS["global_planner"])
    )
    local_planner: LocalPlannerConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("local_planner", DEFAULT_PLUGINS["local_planner"])
    )
    slam: SlamConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: _default("slam", DEFAULT_PLUGINS["slam"]),
        description="used while a map_area task maps",
    )
    odometry: OdometrySource = Field(default_factory=OdometrySource)
    costmap: CostmapConfig = Field(default_factory=CostmapConfig)
    navigation: NavigationConfig = Field(default_factory=NavigationConfig)
    collision_monitor: CollisionMonitorConfig = Field(
        default_factory=CollisionMonitorConfig,
        description="Nav2's collision monitor between the controller and the wheels, on the "
        "raw lidar points; on by default with zones sized from the footprint",
    )
