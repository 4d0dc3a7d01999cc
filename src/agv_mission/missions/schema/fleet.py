"""The ``fleet:`` block of a fleet mission: the fleet layer's plugin slots."""

from __future__ import annotations

from typing import Any

from pydantic import Field

from agv_mission.missions.schema.base import StrictModel


class Fleet(StrictModel):
    """The fleet layer's plugins, each chosen by ``type`` (fleet.md)."""

    dispatcher: dict[str, Any] = Field(
        default_factory=lambda: {"type": "quickest_finish"},
        description="who gets a fleet task without `robot:` (plugin slot `dispatcher`)",
    )
    traffic: dict[str, Any] = Field(
        default_factory=lambda: {"type": "reservations"},
        description="keeps robots out of each other's way (plugin slot `traffic`)",
    )
