"""Double Merge and Halting Car: synthetic multi-agent driving scenarios on carlo_lite.

Plain scenario classes (`DoubleMerge`, `HaltingCar`, registered in `SCENARIOS`) draw randomised
episodes from a seed and drive every car with an expert policy; `rollout` records one episode as
numpy arrays, and `rollout_batch` records many episodes at once as one batched world (the same
arrays, several times faster). The PettingZoo environments are the submodules `double_merge_v0`,
`double_merge_v1`, `halting_car_v0` ... `halting_car_v3` (imported on demand:
`from scenarios import halting_car_v1`). The v1 scenarios (`ReactiveDoubleMerge`,
`ReactiveHaltingCar`, registered as "double_merge_v1" and "halting_car_v1") make each labelled
car's observed state decide the attending car's future; Halting Car v2 (`LateBrakeHaltingCar`,
"halting_car_v2") leaves the follower's own history nothing of it, and Halting Car v3
(`FixedBrakeHaltingCar`, "halting_car_v3") makes the leader's observed braking the same in every
`stop` scene; docs/scenarios.md compares the versions.
"""

import importlib
from types import ModuleType

from scenarios.base import ROLE_NAMES, Scenario, ScenarioConfig, ScenarioPlan
from scenarios.batched_rollout import rollout_batch
from scenarios.double_merge import DoubleMerge, DoubleMergeConfig, DoubleMergePlan
from scenarios.double_merge_reactive import (
    ReactiveDoubleMerge,
    ReactiveDoubleMergeConfig,
    ReactiveDoubleMergePlan,
)
from scenarios.halting_car import HaltingCar, HaltingCarConfig, HaltingCarPlan
from scenarios.halting_car_fixed_brake import FixedBrakeHaltingCar, FixedBrakeHaltingCarConfig
from scenarios.halting_car_late import LateBrakeHaltingCar, LateBrakeHaltingCarConfig
from scenarios.halting_car_reactive import (
    ReactiveHaltingCar,
    ReactiveHaltingCarConfig,
    ReactiveHaltingCarPlan,
)
from scenarios.rollout import Episode, advance, rollout

ENV_MODULES: dict[str, str] = {  # scenario name -> its PettingZoo environment module
    "double_merge": "scenarios.double_merge_v0",
    "double_merge_v1": "scenarios.double_merge_v1",
    "halting_car": "scenarios.halting_car_v0",
    "halting_car_v1": "scenarios.halting_car_v1",
    "halting_car_v2": "scenarios.halting_car_v2",
    "halting_car_v3": "scenarios.halting_car_v3",
}

SCENARIOS: dict[str, type[Scenario]] = {
    DoubleMerge.name: DoubleMerge,
    ReactiveDoubleMerge.name: ReactiveDoubleMerge,
    HaltingCar.name: HaltingCar,
    ReactiveHaltingCar.name: ReactiveHaltingCar,
    LateBrakeHaltingCar.name: LateBrakeHaltingCar,
    FixedBrakeHaltingCar.name: FixedBrakeHaltingCar,
}


def env_module(name: str) -> ModuleType:
    """The PettingZoo environment module of scenario `name` (`parallel_env`, `env`, `raw_env`)."""
    if name not in ENV_MODULES:
        raise ValueError(f"unknown scenario {name!r}; choose from {', '.join(sorted(ENV_MODULES))}")
    return importlib.import_module(ENV_MODULES[name])


__all__ = [
    "ENV_MODULES",
    "ROLE_NAMES",
    "SCENARIOS",
    "DoubleMerge",
    "DoubleMergeConfig",
    "DoubleMergePlan",
    "Episode",
    "FixedBrakeHaltingCar",
    "FixedBrakeHaltingCarConfig",
    "HaltingCar",
    "HaltingCarConfig",
    "HaltingCarPlan",
    "LateBrakeHaltingCar",
    "LateBrakeHaltingCarConfig",
    "ReactiveDoubleMerge",
    "ReactiveDoubleMergeConfig",
    "ReactiveDoubleMergePlan",
    "ReactiveHaltingCar",
    "ReactiveHaltingCarConfig",
    "ReactiveHaltingCarPlan",
    "Scenario",
    "ScenarioConfig",
    "ScenarioPlan",
    "advance",
    "env_module",
    "rollout",
    "rollout_batch",
]
