"""Typed settings of a config section: one frozen dataclass per stage, built
from the validated section, so that the schema alone declares each key and
its default.

A stage declares its class with a field per key of its section (no defaults:
:func:`gs2e.config.load_section` fills them from the schema), resolves its
section once in its CLI (:meth:`Section.load`) and passes the object on;
the stage's functions take only that (:func:`require`).
``tests/test_settings.py`` holds every class's fields equal to its
section's keys. (No table of the classes here: every stage imports this
module, and a table of module names would tie each stage's code version to
all the others'.)

Example::

    @dataclass(frozen=True)
    class SfmSettings(Section):
        SECTION: ClassVar[str] = "sfm"
        matcher: str
        ...

    cfg = SfmSettings.load(args.config_json, args.config)  # the CLI, once
    cfg = SfmSettings.defaults(matcher="exhaustive")      # tests, validated
"""

from __future__ import annotations

import copy
import dataclasses
import json
from typing import Any, ClassVar, Mapping, TypeVar

from gs2e.common.errors import ConfigError

S = TypeVar("S", bound="Section")
T = TypeVar("T")


def require(settings: Any, cls: type[T], where: str) -> T:
    """``settings`` if it is a ``cls`` (typed settings); TypeError naming
    ``where`` otherwise: a config section is resolved once, before it reaches
    a stage, and never again (a dict is not resolved on the way)."""
    if not isinstance(settings, cls):
        raise TypeError(f"{where} takes {cls.__name__}, not {type(settings).__name__} "
                        "(a config section is resolved once, into its typed settings, before a stage runs)")
    return settings


class Section:
    """Base of a frozen dataclass that holds one config section's keys."""

    SECTION: ClassVar[str]

    @classmethod
    def from_section(cls: type[S], section: Mapping[str, Any]) -> S:
        """The settings of a validated section (every key present, defaults
        filled). Raises ConfigError naming a key with no field or a field
        with no key: a key is never dropped silently."""
        names = [f.name for f in dataclasses.fields(cls)]
        extra = sorted(set(section) - set(names))
        if extra:
            raise ConfigError(f"config key '{cls.SECTION}.{extra[0]}': not a setting of {cls.__name__}")
        missing = [n for n in names if n not in section]
        if missing:
            raise ConfigError(f"config key '{cls.SECTION}.{missing[0]}' is missing (load the section "
                              "through gs2e.config.load_section, which fills the defaults)")
        return cls(**{n: copy.deepcopy(section[n]) for n in names})

    @classmethod
    def load(cls: type[S], text: str | None = None, path: str | None = None) -> S:
        """A stage CLI's settings, resolved once: the section from
        ``--config-json`` text, a YAML config file, or the defaults
        (:func:`gs2e.config.load_section`: validated and checked)."""
        from gs2e.config import load_section

        return cls.from_section(load_section(cls.SECTION, text, path))

    @classmethod
    def defaults(cls: type[S], **over: Any) -> S:
        """The schema's defaults with ``over`` replacing keys, validated and
        checked as the CLI does (ConfigError naming the key)."""
        from gs2e.config import load_section

        return cls.from_section(load_section(cls.SECTION, text=json.dumps(over) if over else None))

    def replace(self: S, **over: Any) -> S:
        """A copy with ``over`` replacing keys, validated again."""
        return type(self).defaults(**{**self.as_dict(), **over})

    def as_dict(self) -> dict[str, Any]:
        """The section as a plain dict (a copy) with its keys sorted, as the
        workflow passes it (:func:`gs2e.config.section_json`): what outputs
        record and hash."""
        return {n: copy.deepcopy(getattr(self, n)) for n in sorted(f.name for f in dataclasses.fields(self))}
