"""The registry of scenario versions, built from `scenarios.versions` (the one place where
families declare their versions), and how names resolve.

A version is `family_vN` (Gymnasium's naming): the code that runs it (a `Scenario` class: plan
sampling and expert) and its settings (config fields), `scenarios.versioning.ScenarioVersion`.
From the registry come the PettingZoo environment modules (`scenarios.halting_car_v3`), the
generator's choices, the docs table of versions (`versions_markdown`) and the tests'
parametrisation.

Names: an exact `family_vN` is that version; a bare family name (`halting_car`) is its latest
version, with a one-line notice naming it, as `gymnasium.make("CartPole")` does. Dataset
files record the exact version; files written before versioned names record the bare family
name for v0 (`stored_version`).
"""

from __future__ import annotations

import difflib
import warnings
from typing import TYPE_CHECKING

from scenarios.versioning import ScenarioVersion
from scenarios.versions import FAMILY_VERSIONS

if TYPE_CHECKING:
    from scenarios.base import Scenario, ScenarioConfig


class LatestVersionNotice(UserWarning):
    """An unversioned scenario name was resolved to the family's latest version."""


FAMILIES: dict[str, tuple[ScenarioVersion, ...]] = {
    versions[0].family: versions for versions in FAMILY_VERSIONS
}  # family -> its versions, oldest first
VERSIONS: dict[str, ScenarioVersion] = {
    version.name: version for versions in FAMILIES.values() for version in versions
}  # family_vN -> version, in declaration order


def version_names() -> list[str]:
    """Every registered version name, `family_vN`, in declaration order."""
    return list(VERSIONS)


def latest(family: str) -> ScenarioVersion:
    """The newest version of `family`."""
    return FAMILIES[family][-1]


def lookup(name: str) -> tuple[ScenarioVersion, str | None]:
    """The version `name` means, and a notice when it is a bare family name (the latest
    version), else None. ValueError listing the valid names for anything else."""
    if name in VERSIONS:
        return VERSIONS[name], None
    if name in FAMILIES:
        version = latest(name)
        return version, (
            f"using the latest version {version.name} for the unversioned name {name!r} "
            f"(name a version, e.g. {name}_v0, to pin one)"
        )
    close = difflib.get_close_matches(str(name), [*VERSIONS, *FAMILIES], n=1)
    hint = f" (did you mean {close[0]}?)" if close else ""
    raise ValueError(f"unknown scenario {name!r}{hint}; {choices_text()}")


def resolve(name: str, *, stacklevel: int = 2) -> ScenarioVersion:
    """`lookup`, with the notice as a `LatestVersionNotice` warning (attributed `stacklevel`
    frames up, as `warnings.warn` counts them)."""
    version, notice = lookup(name)
    if notice is not None:
        warnings.warn(notice, LatestVersionNotice, stacklevel=stacklevel)
    return version


def make(name: str, config: ScenarioConfig | None = None) -> Scenario:
    """The scenario `name` resolves to (`resolve`), with its version's settings or `config`."""
    return resolve(name, stacklevel=3).make(config)


def stored_version(name: str) -> ScenarioVersion:
    """The version a dataset file's scenario name records: exact names as they are; a bare
    family name, which files written before versioned names hold, is that family's v0."""
    if name in FAMILIES:
        return FAMILIES[name][0]
    return lookup(name)[0]


def choices_text() -> str:
    """The valid names in one line, for error messages and help."""
    return f"choose from {', '.join(VERSIONS)} (or {', '.join(FAMILIES)} for the latest version)"


def versions_markdown() -> str:
    """The docs table of every version: name, code, what changed, why, and the settings its
    entry changed (from the previous version's, or from the code's defaults for new code)."""
    rows = [
        "| version | code | what changed | why | settings changed |",
        "|---|---|---|---|---|",
    ]
    for version in VERSIONS.values():
        settings = ", ".join(f"`{key}={value}`" for key, value in version.own_settings.items())
        rows.append(
            f"| `{version.name}` | `{version.scenario_class.__name__}` | {version.changes} | "
            f"{version.why} | {settings or '-'} |"
        )
    return "\n".join(rows) + "\n"
