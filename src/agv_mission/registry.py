"""The one plugin registry: every pluggable slot maps a ``type`` name to a class.

A plugin is a class with a ``Config`` attribute (a pydantic model whose ``type``
field is a ``Literal`` of the plugin's name). Built-in plugins register with the
``@register(slot, name)`` decorator; third-party ones through the entry-point
group ``agv_mission.plugins`` with names ``<slot>.<type>``, e.g.
``global_planner.my_rrt = my_pkg.planner:MyRrt``.
"""

from __future__ import annotations

from collections.abc import Callable
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any, TypeVar

SLOTS = ("localization", "slam", "global_planner", "local_planner")
ENTRY_POINT_GROUP = "agv_mission.plugins"

T = TypeVar("T", bound=type)


class UnknownPluginError(KeyError):
    """Raised when a slot has no plugin of the requested type."""


class Registry:
    """Maps (slot, type name) to a plugin class."""

    def __init__(self) -> None:
        self._plugins: dict[str, dict[str, type]] = {slot: {} for slot in SLOTS}
        self._loaded = False

    def register(self, slot: str, name: str) -> Callable[[T], T]:
        """Class decorator: make ``cls`` the plugin ``name`` of ``slot``."""
        if slot not in self._plugins:
            raise ValueError(f"unknown plugin slot {slot!r}; slots are {', '.join(SLOTS)}")

        def decorate(cls: T) -> T:
            self._plugins[slot][name] = cls
            return cls

        return decorate

    def get(self, slot: str, name: str) -> type:
        self.load()
        try:
            return self._plugins[slot][name]
        except KeyError:
            known = ", ".join(sorted(self._plugins.get(slot, {})))
            raise UnknownPluginError(f"no {slot} plugin {name!r} (known: {known})") from None

    def names(self, slot: str) -> list[str]:
        self.load()
        return sorted(self._plugins[slot])

    def configs(self, slot: str) -> list[type]:
        """The pydantic config models of every plugin of ``slot``."""
        self.load()
        return [self._plugins[slot][n].Config for n in sorted(self._plugins[slot])]

    def create(self, slot: str, config: Any, **kwargs: Any) -> Any:
        """Instantiate the plugin named by ``config.type`` with its config."""
        return self.get(slot, config.type)(config, **kwargs)

    def load(self) -> None:
        """Import the built-in plugins and those announced by entry points (once)."""
        if self._loaded:
            return
        for module in _BUILTIN_MODULES:
            import_module(module)
        for ep in entry_points(group=ENTRY_POINT_GROUP):
            slot, _, name = ep.name.partition(".")
            self.register(slot, name)(ep.load())
        self._loaded = True


_BUILTIN_MODULES = (
    "agv_mission.localization.ground_truth",
    "agv_mission.localization.odometry",
    "agv_mission.localization.amcl",
    "agv_mission.mapping.slam",
    "agv_mission.mapping.graph_slam",
    "agv_mission.planners.ompl_planner",
    "agv_mission.planners.grid_astar",
    "agv_mission.planners.mpc",
    "agv_mission.planners.pure_pursuit",
)

registry = Registry()
register = registry.register
