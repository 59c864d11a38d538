"""Expert episodes shared by the scenario test modules, rolled out once per test session, for
every registered version (`scenarios.VERSIONS`)."""

from __future__ import annotations

from functools import cache

from scenarios import VERSIONS, Episode, rollout_batch
from scenarios.junction import JunctionScenario

NUM_SAFETY_SEEDS = 200
CASES = [
    (name, case) for name, version in VERSIONS.items() for case in version.scenario_class.case_names
]
JUNCTIONS = [n for n, v in VERSIONS.items() if issubclass(v.scenario_class, JunctionScenario)]
STRAIGHT_CASES = [(name, case) for name, case in CASES if name not in JUNCTIONS]  # one road
JUNCTION_CASES = [(name, case) for name, case in CASES if name in JUNCTIONS]


@cache
def scenario(name: str):
    return VERSIONS[name].make()


@cache
def episodes(name: str, case: str) -> tuple[Episode, ...]:
    """The expert's episodes for seeds 0..199, computed once per test session."""
    seeds = range(NUM_SAFETY_SEEDS)
    return tuple(rollout_batch(VERSIONS[name].make(), seeds, [case] * len(seeds)))


def plan_of(name: str, seed: int, case: str):
    return VERSIONS[name].make().plan(seed, case)
