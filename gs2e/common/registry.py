"""Registries of named parts: the benchmark's tasks (:mod:`gs2e.bench.tasks`),
the export formats (:mod:`gs2e.export.formats`), the event models
(:mod:`gs2e.events.models`) and the sensor presets (:mod:`gs2e.events.sensors`).

An entry names its code as a ``"module:function"`` string, imported only
when it runs, so that a registry stays light (the Snakefile and the CLI's
argument parsers read them). :mod:`gs2e.codeversion` follows the gs2e
modules such strings name in every module that imports this one, as it does
for modules that import with ``importlib``.

Plug-ins: an installed package adds entries through Python entry points
(:data:`PLUGIN_GROUPS`; ``[project.entry-points."gs2e.bench_tasks"]`` in its
pyproject.toml, ``name = "module:object"``), each object of the registry's
kind (a Task, a Format, a model class, a Sensor) under the entry point's
name. Each registry loads its group when it is imported
(:func:`load_plugins`); the config schema lists the names of every group's
plug-ins in its enums without importing them (:func:`plugin_names`).
"""

from __future__ import annotations

import importlib
import re
from typing import Callable, TypeVar

T = TypeVar("T")


def resolve(fn: Callable | str) -> Callable:
    """``fn`` itself if callable, else the function a ``"module:function"`` string names."""
    if callable(fn):
        return fn
    module, name = fn.split(":")
    return getattr(importlib.import_module(module), name)


def add(registry: dict[str, T], name: str, entry: T, what: str, pattern: str = r"[a-z][a-z0-9_]*") -> T:
    """Put ``entry`` in ``registry`` under ``name``, which must match ``pattern``
    (ValueError naming ``what`` otherwise); a name registered again is replaced."""
    if not re.fullmatch(pattern, name):
        raise ValueError(f"{what} name {name!r}: it must match {pattern}")
    dict.__setitem__(registry, name, entry)
    return entry


# entry-point group -> the config schema's enum its names join (the registry that
# loads it: gs2e.bench.tasks, gs2e.export.formats, gs2e.events.models, gs2e.events.sensors)
PLUGIN_GROUPS: dict[str, tuple[str, ...]] = {
    "gs2e.bench_tasks": ("bench", "tasks", "items"),
    "gs2e.export_formats": ("export", "formats", "items"),
    "gs2e.event_models": ("events", "model"),
    "gs2e.sensors": ("events", "sensor"),
}


def _entry_points(group: str):
    from importlib.metadata import entry_points

    return sorted(entry_points(group=group), key=lambda ep: ep.name)


def plugin_names(group: str) -> list[str]:
    """Names of the installed plug-ins of an entry-point group (nothing imported)."""
    return [ep.name for ep in _entry_points(group)]


class PluginRegistry(dict):
    """A registry (name -> entry) that adds its entry-point group's plug-ins
    (:func:`load_plugins`, through ``register``) the first time it is read."""

    def __init__(self, group: str):
        super().__init__()
        self.group = group
        self._loader: tuple[Callable, Callable] | None = None

    def plugins(self, register: Callable, name_of: Callable) -> None:
        """How to add a plug-in: ``register(obj)``, and its name ``name_of(obj)``."""
        self._loader = (register, name_of)

    def _load(self) -> None:
        if self._loader is not None:
            register, name_of = self._loader
            self._loader = None
            load_plugins(self.group, register, name_of)

    def __getitem__(self, key):
        self._load()
        return super().__getitem__(key)

    def __contains__(self, key) -> bool:
        self._load()
        return super().__contains__(key)

    def __iter__(self):
        self._load()
        return super().__iter__()

    def __len__(self) -> int:
        self._load()
        return super().__len__()

    def get(self, key, default=None):
        self._load()
        return super().get(key, default)

    def keys(self):
        self._load()
        return super().keys()

    def values(self):
        self._load()
        return super().values()

    def items(self):
        self._load()
        return super().items()


def load_plugins(group: str, register: Callable, name_of: Callable) -> None:
    """Import every installed plug-in of ``group`` and ``register`` it; the
    object's own name (``name_of(obj)``) must be the entry point's. A plug-in
    that fails to import, or names itself otherwise, is a one-line
    ConfigError naming it and its distribution."""
    from gs2e.common.errors import ConfigError

    for ep in _entry_points(group):
        dist = getattr(ep, "dist", None)
        where = f"plug-in '{ep.name}' ({ep.value}, package {dist.name if dist else 'unknown'}) of {group}"
        try:
            obj = ep.load()
        except Exception as exc:  # anything a foreign import raises
            raise ConfigError(f"{where}: cannot be imported ({type(exc).__name__}: {exc})") from exc
        if name_of(obj) != ep.name:
            raise ConfigError(f"{where}: the object's name is {name_of(obj)!r}, not the entry point's")
        register(obj)
