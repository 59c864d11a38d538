"""Double Merge, Halting Car (straight roads), Unprotected Left Turn and Roundabout Entry
(junctions): synthetic multi-agent driving scenarios on carlo_lite, as versioned families
(Gymnasium's naming: `double_merge_v1`, `halting_car_v3`, `left_turn_v0`).

    import scenarios
    env = scenarios.halting_car_v3.parallel_env()          # PettingZoo, one scene
    vec = scenarios.halting_car_v3.vector_env(num_envs=64)  # many scenes at once, for RL
    scenario = scenarios.make("halting_car_v3")            # plain class: plans and expert
    episode = scenarios.rollout(scenario, seed=0, case="stop")

Versions are data (`scenarios.versions`, one entry each); `make`, `version` and `env_module`
take an exact name or a bare family name, which means the latest version and says so
(`LatestVersionNotice`). Each version has an environment module `scenarios.<name>`
(`parallel_env`, `env`, `raw_env`, `vector_env`). `rollout` records one episode as numpy arrays,
`rollout_batch` many at once as one batched world (the same arrays, several times faster);
docs/scenarios.md compares the versions.
"""

from types import ModuleType

from scenarios.base import ROLE_NAMES, Scenario, ScenarioConfig, ScenarioPlan
from scenarios.double_merge import DoubleMerge, DoubleMergeConfig, DoubleMergePlan
from scenarios.double_merge_reactive import (
    ReactiveDoubleMerge,
    ReactiveDoubleMergeConfig,
    ReactiveDoubleMergePlan,
)
from scenarios.env_modules import install
from scenarios.halting_car import HaltingCar, HaltingCarConfig, HaltingCarPlan
from scenarios.halting_car_reactive import (
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    ReactiveHaltingCarPlan,
)
from scenarios.junction import JunctionConfig, JunctionPlan, JunctionScenario
from scenarios.left_turn import LeftTurn, LeftTurnConfig, LeftTurnPlan
from scenarios.registry import (
    FAMILIES,
    VERSIONS,
    LatestVersionNotice,
    choices_text,
    lookup,
    make,
    resolve,
    stored_version,
    version_names,
)
from scenarios.rollout import Episode, advance, rollout, rollout_batch
from scenarios.roundabout_entry import (
    RoundaboutEntry,
    RoundaboutEntryConfig,
    RoundaboutEntryPlan,
)
from scenarios.versioning import ScenarioVersion

ENV_MODULES = install(globals())  # version name -> scenarios.<name>


def version(name: str) -> ScenarioVersion:
    """The registered version `name` (a bare family name: its latest, with a notice)."""
    return resolve(name, stacklevel=3)


def env_module(name: str) -> ModuleType:
    """The PettingZoo environment module of version `name` (`parallel_env`, `env`, `raw_env`,
    `vector_env`); a bare family name is its latest version, with a notice."""
    return ENV_MODULES[resolve(name, stacklevel=3).name]


__all__ = [
    "ENV_MODULES",
    "FAMILIES",
    "ROLE_NAMES",
    "VERSIONS",
    "DoubleMerge",
    "DoubleMergeConfig",
    "DoubleMergePlan",
    "Episode",
    "HaltingCar",
    "HaltingCarConfig",
    "HaltingCarPlan",
    "JunctionConfig",
    "JunctionPlan",
    "JunctionScenario",
    "LatestVersionNotice",
    "LeftTurn",
    "LeftTurnConfig",
    "LeftTurnPlan",
    "ReactiveDoubleMerge",
    "ReactiveDoubleMergeConfig",
    "ReactiveDoubleMergePlan",
    "ReactiveHaltingCar",
    "ReactiveHaltingCarConfig",
    "ReactiveHaltingCarPlan",
    "RoundaboutEntry",
    "RoundaboutEntryConfig",
    "RoundaboutEntryPlan",
    "Scenario",
    "ScenarioConfig",
    "ScenarioPlan",
    "ScenarioVersion",
    "advance",
    "choices_text",
    "env_module",
    "lookup",
    "make",
    "resolve",
    "rollout",
    "rollout_batch",
    "stored_version",
    "version",
    "version_names",
    *ENV_MODULES,
]
