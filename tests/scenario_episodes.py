"""Expert episodes shared by the scenario test modules, rolled out once per test session."""

from __future__ import annotations

from functools import cache

import numpy as np

from scenarios import SCENARIOS, Episode, rollout

NUM_SAFETY_SEEDS = 200
CASES = [(name, case) for name, cls in SCENARIOS.items() for case in cls.case_names]


@cache
def scenario(name: str):
    return SCENARIOS[name]()


@cache
def episodes(name: str, case: str) -> tuple[Episode, ...]:
    """The expert's episodes for seeds 0..199, computed once per test session."""
    return tuple(rollout(SCENARIOS[name](), seed, case) for seed in range(NUM_SAFETY_SEEDS))


def plan_of(name: str, seed: int, case: str):
    return SCENARIOS[name]().sample_plan(np.random.default_rng(seed), case)
