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
    other's lane; case `major`: green starts behind, `minor`: ahead), with a reactive expert
    (`scenarios.double_merge_reactive`): the rear car lets the front car in, holding back from
    the start to its cruise minus a yield speed of 0.5 to 3 m/s drawn per episode; the front
    car starts its lane change at its planned time (0.5 to 2 s) only once the bumper gap to the
    rear car is at least 2 m plus 1 s of the rear car's speed, and until then drives 1 m/s
    above the cruise; once it cuts in, the rear car follows it with the Intelligent Driver
    Model (time headway 1.2 s, desired speed the cruise, reaction delay 0.4 s) and, as in v0,
    moves next to the centre line and merges 0.4 s after the front car has settled. Both lane
    changes take 3.5 s. `car_2` ... `car_21` are distractors. All randomness comes from the
    reset seed; the ranges are the fields of `scenarios.ReactiveDoubleMergeConfig` (the
    `config` argument takes one).
"""
HISTORY = """## Version History
    - v1: the rear car yields and then follows the front car (IDM with a delay), the front
      car waits for a safe gap; hidden per-episode durations and delays fixed.
    - v0: first version.
    """
CHANGES = {
    '-1 for none: the main cars attend to each other, the paper\'s "Correct"\n    oracle), '
    "`interaction` (the rear main car is waiting next to the centre line)": "-1 for none: the\n"
    "    rear main car attends to the front one throughout, the front one to the rear one from\n"
    "    its planned start until it starts its lane change), `interaction` (the front car is\n"
    "    watching the rear car or the rear car is waiting next to the centre line)",
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
