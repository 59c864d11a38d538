"""Double Merge v1 as a PettingZoo environment: `parallel_env()`, `env()` (AEC) and `raw_env`.

The user manual is the docstring of `DoubleMergeV1Env`, built from v0's (spaces, rewards,
episode end and arguments are unchanged) with v1's description, labels and version history:
`python -m pydoc scenarios.double_merge_v1.DoubleMergeV1Env`.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import AECEnv

from scenarios.double_merge_reactive import ReactiveDoubleMerge
from scenarios.double_merge_v0 import DoubleMergeEnv
from scenarios.env import env_metadata, revised_manual

DESCRIPTION = """Double Merge v1: the two main cars swap lanes, each reacting to the other.

    ## Description
    As v0 (the green car `car_0` in lane 2 and the brown car `car_1` in lane 1 want each
    other's lane; case `major`: green starts behind, `minor`: ahead; the front car starts its
    lane change 0.5 to 2 s into the episode), with a reactive expert
    (`scenarios.double_merge_reactive`): once the rear car sees the front car 0.2 m out of its
    lane centre it follows it with the Intelligent Driver Model (time headway 1.5 s, desired
    speed the cruise, reaction delay 0.4 s), so it brakes as much as the observed gap and
    speeds ask; as in v0 it moves next to the centre line and merges 0.4 s after the front car
    has settled. The front car paces the rear car: it tracks the rear car's speed as seen
    0.8 s earlier plus 1 m/s, so it answers the rear car's braking mostly after the observed
    window. Both lane changes take 3.5 s. `car_2` ... `car_21` are distractors. All
    randomness comes from the reset seed; the ranges are the fields of
    `scenarios.ReactiveDoubleMergeConfig` (the `config` argument takes one).
"""
HISTORY = """## Version History
    - v1: the rear car follows the front car (IDM with a delay) once it sees it leave its
      lane, the front car paces the rear car (delayed); hidden durations and delays fixed.
    - v0: first version.
    """
CHANGES = {
    '-1 for none: the main cars attend to each other, the paper\'s "Correct"\n    oracle), '
    "`interaction` (the rear main car is waiting next to the centre line)": "-1 for none: the\n"
    "    main cars attend to each other, each reacting to the other), `interaction` (from the\n"
    "    rear car seeing the front car leave its lane until it starts its own lane change)",
    "`scenarios.rollout(DoubleMerge(),": "`scenarios.rollout(ReactiveDoubleMerge(),",
    "| DoubleMergeConfig  |": "| ReactiveDoubleMergeConfig |",
}


class DoubleMergeV1Env(DoubleMergeEnv):
    __doc__ = revised_manual(DoubleMergeEnv.__doc__, DESCRIPTION, HISTORY, CHANGES)

    scenario_class = ReactiveDoubleMerge
    metadata = env_metadata("double_merge_v1", ReactiveDoubleMerge)


raw_env = DoubleMergeV1Env  # the unwrapped parallel environment


def parallel_env(**kwargs: Any) -> DoubleMergeV1Env:
    """The Double Merge v1 parallel environment (see `DoubleMergeV1Env` for the arguments)."""
    return DoubleMergeV1Env(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """Double Merge v1 with the AEC API (agents act in turn, `parallel_to_aec`)."""
    return parallel_to_aec(DoubleMergeV1Env(**kwargs))
