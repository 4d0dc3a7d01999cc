"""The one plugin registry: every pluggable slot maps a ``type`` name to a class.

Plugins, built-in or third-party, are announced the same way: entry points of the group
``agv_mission.plugins`` named ``<slot>.<type>`` (see ``pyproject.toml``). An entry point
names either

* the plugin class, which has a ``Config`` attribute (a :class:`PluginConfig` whose
  ``type`` field is a ``Literal`` of the plugin's name), or
* the plugin's config class, whose ``plugin`` class variable names the plugin class as
  ``"module:Class"``. The built-ins do this: the schema then needs only their light
  config modules, and MuJoCo, casadi or OMPL are imported when a run builds a plugin.

An entry point is loaded when its plugin is first named (or when the schema lists every
plugin of a slot). One that fails to load is reported with a warning and left out, so a
broken third-party plugin does not break missions that do not use it. A name announced
twice is a warning; the later one wins.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass
from importlib import import_module
from importlib.metadata import entry_points
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict

SLOTS = (
    "localization",
    "slam",
    "global_planner",
    "local_planner",
    "behavior",
    "dispatcher",
    "traffic",
)
ENTRY_POINT_GROUP = "agv_mission.plugins"

T = TypeVar("T", bound=type)


class PluginConfig(BaseModel):
    """Base of every plugin's configuration block: unknown keys are errors; its validator
    is built when first used (a mission names few of the plugins the schema lists)."""

    model_config = ConfigDict(extra="forbid", defer_build=True)


class UnknownPluginError(KeyError):
    """Raised when a slot has no (loadable) plugin of the requested type."""


class PluginWarning(UserWarning):
    """A plugin announced twice, or one that failed to load."""


@dataclass
class _Entry:
    value: str  # what it names ("module:Class"), for messages
    load: Callable[[], Any]  # returns the plugin class or its config class
    dist: Any = None  # the distribution that announced it, if any
    target: Any = None
    error: str | None = None
    loaded: bool = False

    @property
    def source(self) -> str:
        """Where it was announced, for messages. The distribution's name is read only
        here: it parses the distribution's metadata, which a start-up does not need."""
        dist = getattr(self.dist, "name", None)
        return self.value + (f" (from {dist})" if dist else "")


def load_object(spec: str) -> Any:
    """The object ``"package.module:Name"`` names (``Name`` may be dotted)."""
    module, _, attr = spec.partition(":")
    obj: Any = import_module(module)
    for part in attr.split(".") if attr else ():
        obj = getattr(obj, part)
    return obj


class Registry:
    """Maps (slot, type name) to a plugin class and its config model."""

    def __init__(self, group: str = ENTRY_POINT_GROUP) -> None:
        self.group = group
        self._entries: dict[str, dict[str, _Entry]] = {slot: {} for slot in SLOTS}
        self._discovered = False

    # ------------------------------------------------------------------ announcing

    def register(self, slot: str, name: str) -> Callable[[T], T]:
        """Class decorator: make ``cls`` the plugin ``name`` of ``slot`` in this process
        (for experiments and tests; installed plugins use entry points)."""
        _check_slot(slot)

        def decorate(cls: T) -> T:
            self._discover()
            self._add(slot, name, _Entry(f"{cls.__module__}.{cls.__qualname__}", lambda: cls))
            return cls

        return decorate

    def _add(self, slot: str, name: str, entry: _Entry) -> None:
        old = self._entries[slot].get(name)
        if old is not None:
            warnings.warn(
                f"{slot} plugin {name!r} is registered twice ({old.source}, then "
                f"{entry.source}); using {entry.source}",
                PluginWarning,
                stacklevel=3,
            )
        self._entries[slot][name] = entry

    def _discover(self) -> None:
        """Read the entry points (once); nothing is imported yet."""
        if self._discovered:
            return
        self._discovered = True
        for ep in entry_points(group=self.group):
            slot, _, name = ep.name.partition(".")
            entry = _Entry(ep.value, ep.load, ep.dist)
            if slot not in SLOTS or not name:
                warnings.warn(
                    f"entry point {ep.name!r} = {entry.source} is not named <slot>.<type> "
                    f"with a slot of {', '.join(SLOTS)}; ignored",
                    PluginWarning,
                    stacklevel=3,
                )
                continue
            self._add(slot, name, entry)
        if not any(self._entries.values()):
            raise RuntimeError(
                f"no plugins are registered in the entry-point group {self.group!r}: the "
                "installed metadata of agv-mission is out of date; reinstall it "
                "(pip install --no-deps -e .)"
            )

    # ------------------------------------------------------------------ loading

    def _load(self, slot: str, name: str) -> _Entry:
        _check_slot(slot)
        self._discover()
        entry = self._entries[slot].get(name)
        if entry is None:
            known = ", ".join(self.names(slot))
            raise UnknownPluginError(f"no {slot} plugin {name!r} (known: {known})")
        if not entry.loaded:
            entry.loaded = True
            try:
                target = entry.load()
                _config_of(target)
                entry.target = target
            except Exception as exc:  # a broken plugin must not take the others down
                entry.error = f"{type(exc).__name__}: {exc}"
                warnings.warn(
                    f"{slot} plugin {name!r} ({entry.source}) failed to load: {entry.error}",
                    PluginWarning,
                    stacklevel=3,
                )
        if entry.error is not None:
            raise UnknownPluginError(
                f"{slot} plugin {name!r} ({entry.source}) failed to load: {entry.error}"
            )
        return entry

    def config(self, slot: str, name: str) -> type[PluginConfig]:
        """The config model of plugin ``name`` (imports only what the config needs)."""
        return _config_of(self._load(slot, name).target)

    def get(self, slot: str, name: str) -> type:
        """The plugin class ``name`` of ``slot``."""
        target = self._load(slot, name).target
        if isinstance(target, type) and issubclass(target, PluginConfig):
            return load_object(target.plugin)  # type: ignore[attr-defined]
        return target

    def names(self, slot: str) -> list[str]:
        """Every announced plugin name of ``slot`` (loaded or not)."""
        _check_slot(slot)
        self._discover()
        return sorted(self._entries[slot])

    def configs(self, slot: str) -> list[type[PluginConfig]]:
        """The config models of every plugin of ``slot`` that loads."""
        out = []
        for name in self.names(slot):
            try:
                out.append(self.config(slot, name))
            except UnknownPluginError:
                continue  # warned about when it failed
        return out

    def errors(self) -> dict[str, str]:
        """``"<slot>.<type>"`` -> why it failed to load, for the plugins that did."""
        return {
            f"{slot}.{name}": entry.error
            for slot, entries in self._entries.items()
            for name, entry in entries.items()
            if entry.error is not None
        }

    def create(self, slot: str, config: Any, **kwargs: Any) -> Any:
        """Instantiate the plugin named by ``config.type`` with its config."""
        return self.get(slot, config.type)(config, **kwargs)


def _check_slot(slot: str) -> None:
    if slot not in SLOTS:
        raise ValueError(f"unknown plugin slot {slot!r}; slots are {', '.join(SLOTS)}")


def _config_of(target: Any) -> type[PluginConfig]:
    """The config model an entry point's target stands for."""
    if isinstance(target, type) and issubclass(target, PluginConfig):
        if not isinstance(getattr(target, "plugin", None), str):
            raise TypeError(f"{target.__name__} names no plugin class ('plugin' class variable)")
        return target
    config = getattr(target, "Config", None)
    if not (isinstance(config, type) and issubclass(config, PluginConfig)):
        raise TypeError(f"{target!r} is neither a plugin (with a Config) nor a PluginConfig")
    return config


registry = Registry()
register = registry.register
