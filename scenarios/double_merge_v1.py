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
    (`scenarios.double_merge_reactive`): the front car starts its lane change at its planned
    time (0.5 to 2 s) only if the bumper gap to the rear car is at least 2 m plus 0.7 to 1.1 s
    of the rear car's speed, and until then drives 2 to 3 m/s above the cruise to open it; the
    rear car keeps its cruise until the front car starts to cut in, then follows it with the
    Intelligent Driver Model (time headway 1.0 to 1.6 s, desired speed 1.05 to 1.2 x the
    cruise, reaction delay 0.4 to 0.6 s), and, as in v0, moves next to the centre line and
    merges once the front car has settled. `car_2` ... `car_21` are distractors. All randomness
    comes from the reset seed; the ranges are the fields of `scenarios.ReactiveDoubleMergeConfig`
    (the `config` argument takes one).
"""
HISTORY = """## Version History
    - v1: the front car waits for a safe gap; the rear car follows it (IDM with a delay).
    - v0: first version.
    """
CHANGES = {
    '-1 for none: the main cars attend to each other, the paper\'s "Correct"\n    oracle), '
    "`interaction` (the rear main car is waiting next to the centre line)": "-1 for none: the\n"
    "    rear main car attends to the front one throughout, the front one to the rear one until\n"
    "    it starts its lane change), `interaction` (the front car is waiting for the gap or the\n"
    "    rear car next to the centre line)",
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
