"""The ``light`` config section, typed, and one resolved condition.

Each field of :class:`LightSettings` is a key of the section; its meaning,
type and default are the schema's (``gs2e/schemas/config.schema.yaml``,
listed in config/README.md). A stage gets one :class:`Condition` (what the
workflow passes a lit run's jobs as ``--light-json``), never the section.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

from gs2e.common.errors import ConfigError
from gs2e.common.settings import Section

RUN_SEP = "@"  # a run is <trajectory>@<condition>


@dataclass(frozen=True)
class LightSettings(Section):
    """The validated ``light`` section (:meth:`Section.from_section`)."""

    SECTION: ClassVar[str] = "light"

    reference_lux: float
    runs: list
    conditions: dict

    def condition(self, name: str) -> "Condition":
        """The named condition, resolved (ConfigError naming the key if unknown)."""
        if name not in self.conditions:
            raise ConfigError(f"light.conditions: no condition '{name}' "
                              f"(choose from {', '.join(sorted(self.conditions))})")
        return Condition(name=name, reference_lux=float(self.reference_lux), **self.conditions[name])


@dataclass(frozen=True)
class Condition:
    """One lighting condition, resolved (built from the validated section:
    :meth:`LightSettings.condition`, :meth:`from_json`): illuminances in lux-equivalents,
    ramp times as fractions of the run's duration, flicker in Hz of the
    light's intensity (twice the mains frequency) with its percent-flicker
    depth (max - min) / (max + min) (IEEE Std 1789-2015)."""

    name: str
    reference_lux: float
    lux: float
    ramp_to_lux: float | None
    ramp_start: float
    ramp_duration: float
    flicker_hz: float
    flicker_depth: float
    flicker_waveform: str

    def to_json(self) -> str:
        """Canonical JSON (sorted keys): what a lit run's jobs get."""
        return json.dumps(asdict(self), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> "Condition":
        """The condition of ``--light-json``, validated against the schema as
        the ``light`` section is (ConfigError on bad JSON, keys or values,
        naming the key)."""
        try:
            d = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"--light-json is not valid JSON: {exc}") from None
        names = {f.name for f in fields(cls)}
        if not isinstance(d, dict) or set(d) != names:
            got = set(d) if isinstance(d, dict) else set()
            bad = sorted((got - names) | (names - got))
            raise ConfigError(f"--light-json: keys differ from a light condition's ({', '.join(bad)})")
        name, ref = d.pop("name"), d.pop("reference_lux")
        return LightSettings.defaults(reference_lux=ref, conditions={name: d}).condition(name)


def split_run(run: str) -> tuple[str, str | None]:
    """(trajectory, condition or None) of a run name ``<trajectory>[@<condition>]``."""
    traj, sep, cond = run.partition(RUN_SEP)
    return traj, (cond if sep else None)


def run_names(trajectories: list[str], runs: list[str]) -> list[str]:
    """Every run of a scene: the listed trajectories (each may name its own
    condition) and each plain one again under every condition of ``runs``
    (``light.runs``), without repeats, in that order."""
    out: dict[str, None] = {}
    for t in trajectories:
        out[t] = None
    for c in runs:
        for t in trajectories:
            if split_run(t)[1] is None:
                out[f"{t}{RUN_SEP}{c}"] = None
    return list(out)


def condition_json(light_section: dict[str, Any], name: str) -> str:
    """``--light-json`` for condition ``name`` of a validated ``light`` section."""
    return LightSettings.from_section(light_section).condition(name).to_json()
