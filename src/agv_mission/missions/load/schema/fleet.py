"""The ``fleet:`` block: the plugins that dispatch tasks and keep robots apart.

Each slot is a union of the ``Config`` models of every plugin registered for it, told
apart by ``type`` (as the ``stack`` block's slots are); a block without ``type`` is the
slot's default plugin, so ``fleet: {traffic: {horizon: 6}}`` tunes the default.
"""

from __future__ import annotations

from typing import Any

from pydantic import Field, model_validator

from agv_mission.missions.load.schema.base import StrictModel
from agv_mission.missions.load.schema.stack import _plugin_union
from agv_mission.registry import registry

DispatcherConfig = _plugin_union("dispatcher")
TrafficConfig = _plugin_union("traffic")

# The plugin a fleet block without ``type`` (or no block at all) selects.
DEFAULT_FLEET_PLUGINS = {"dispatcher": "quickest_finish", "traffic": "reservations"}


class Fleet(StrictModel):
    """How a fleet shares its work and its floor (the mission's ``fleet`` block)."""

    dispatcher: DispatcherConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: registry.config("dispatcher", "quickest_finish")(),
        description="picks the robot for each fleet task that names none, when it is "
        "released (default quickest_finish: Open-RMF's default bidding)",
    )
    traffic: TrafficConfig = Field(  # type: ignore[valid-type]
        default_factory=lambda: registry.config("traffic", "reservations")(),
        description="keeps robots apart: reservations of the space each plan sweeps, "
        "waits, replans, deadlock detection and breaking",
    )

    @model_validator(mode="before")
    @classmethod
    def _default_types(cls, data: Any) -> Any:
        if isinstance(data, dict):
            for slot, name in DEFAULT_FLEET_PLUGINS.items():
                block = data.get(slot)
                if isinstance(block, dict) and "type" not in block:
                    data = {**data, slot: {**block, "type": name}}
        return data
