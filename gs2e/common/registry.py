"""Registries of named parts: the benchmark's tasks (:mod:`gs2e.bench.tasks`)
and the export formats (:mod:`gs2e.export.formats`).

An entry names its code as a ``"module:function"`` string, imported only
when it runs, so that a registry stays light (the Snakefile and the CLI's
argument parsers read them). :mod:`gs2e.codeversion` follows the gs2e
modules such strings name in every module that imports this one, as it does
for modules that import with ``importlib``.
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
    registry[name] = entry
    return entry
