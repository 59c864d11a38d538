"""What a scenario version is: a `Version` entry as a family declares it (`scenarios.versions`)
and the `ScenarioVersion` it becomes, `family_vN` with its code and accumulated settings.

A version that only changes settings reuses the previous version's code and adds its changed
config fields; one that brings new code names its class, whose config class's defaults are its
settings. `scenarios.registry` looks versions up by name.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from scenarios.base import Scenario, ScenarioConfig


@dataclass(frozen=True)
class Version:
    """One entry of a family's version list (`scenarios.versions`).

    code: the `Scenario` class that runs this version, or None to keep the previous version's
        code (a settings-only version).
    settings: config fields that differ from the previous version (from the class defaults
        when `code` is new).
    changes: what changed, one line (the manual's version history, the docs table).
    why: why, a sentence or two (the docs table).
    """

    changes: str
    why: str
    code: type[Scenario] | None = None
    settings: Mapping[str, Any] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ScenarioVersion:
    """A registered version: `family_vN`, its code and its accumulated settings (one object per
    version, compared by identity)."""

    family: str
    title: str  # the family's name in prose, e.g. "Halting Car"
    number: int
    scenario_class: type[Scenario]
    settings: Mapping[str, Any]  # config fields that differ from scenario_class's defaults
    changes: str
    why: str
    own_settings: Mapping[str, Any]  # the fields this version's entry changed

    @property
    def name(self) -> str:
        return f"{self.family}_v{self.number}"

    def config(self, **changes: Any) -> ScenarioConfig:
        """This version's configuration, with `changes` (config fields) on top."""
        return self.scenario_class.config_class(**{**self.settings, **changes})

    def make(self, config: ScenarioConfig | None = None) -> Scenario:
        """The scenario of this version (with `config` instead of the version's, if given)."""
        return self.scenario_class(self.config() if config is None else config, name=self.name)


def family_versions(family: str, title: str, *entries: Version) -> tuple[ScenarioVersion, ...]:
    """The versions of `family`, numbered from 0 in the order given, settings accumulated."""
    versions: list[ScenarioVersion] = []
    for number, entry in enumerate(entries):
        if entry.code is None and not versions:
            raise ValueError(f"{family}_v0 must name its code")
        if entry.code is None:
            code, settings = versions[-1].scenario_class, {**versions[-1].settings}
        else:
            code, settings = entry.code, {}
        settings.update(entry.settings)
        version = ScenarioVersion(
            family,
            title,
            number,
            code,
            MappingProxyType(settings),
            entry.changes,
            entry.why,
            MappingProxyType(dict(entry.settings)),
        )
        version.config()  # validated now: a bad setting fails at import, naming the field
        versions.append(version)
    return tuple(versions)
