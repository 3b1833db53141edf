"""Finding plugins by name: a built-in table first, then the entry points of installed packages.

Drivers (`hubs.drivers.registry`, group `statehub.drivers`) and simulators
(`hubs.sim.registry`, group `statehub.simulators`) are both found this way: the name is
the device type, the object a `DriverPlugin` or `SimulatorPlugin`. Built-in plugins are
named as "module:attribute" and imported on first use, so a hub only loads the
libraries its devices use.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from importlib import metadata
from typing import Generic, TypeVar

P = TypeVar("P")


class PluginError(ValueError):
    """A plugin that is declared but cannot be loaded, or is not what its group expects."""


class PluginTable(Generic[P]):
    def __init__(self, group: str, kind: type[P], builtin: Mapping[str, str]) -> None:
        self.group = group
        self.kind = kind
        self.builtin = dict(builtin)  # name -> "module:attribute"
        self._loaded: dict[str, P] = {}

    def find(self, name: str) -> P | None:
        """The plugin named `name`, or None when neither the table nor an installed package has one.
        Raises PluginError for a plugin that fails to load or has the wrong type."""
        if name in self._loaded:
            return self._loaded[name]
        spec = self.builtin.get(name)
        if spec is not None:
            module, _, attribute = spec.partition(":")
            plugin = self._check(getattr(importlib.import_module(module), attribute), f"built-in {spec}")
            self._loaded[name] = plugin
            return plugin
        points = sorted(metadata.entry_points(group=self.group, name=name), key=lambda p: p.value)
        if not points:
            return None
        if len({p.value for p in points}) > 1:
            raise PluginError(f"entry-point group {self.group!r}: several installed packages provide {name!r} "
                              f"({', '.join(p.value for p in points)}): uninstall all but one")
        point = points[0]
        where = f"entry point {name} = {point.value} (group {self.group!r})"
        try:
            loaded = point.load()
        except Exception as exc:
            raise PluginError(f"{where} cannot be loaded: {type(exc).__name__}: {exc}") from exc
        return self._check(loaded, where)  # not cached: installing a package changes what is found

    def names(self) -> list[str]:
        """Every name the table and the installed packages provide."""
        return sorted(set(self.builtin) | {p.name for p in metadata.entry_points(group=self.group)})

    def _check(self, plugin: object, where: str) -> P:
        if not isinstance(plugin, self.kind):
            raise PluginError(f"{where} is a {type(plugin).__name__}, not a {self.kind.__name__}")
        return plugin
