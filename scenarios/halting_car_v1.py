"""Halting Car v1 as a PettingZoo environment: `parallel_env()`, `env()` (AEC) and `raw_env`.

The user manual is the docstring of `HaltingCarV1Env`, built from v0's (spaces, rewards, episode
end, infos and arguments are unchanged) with v1's description and version history:
`python -m pydoc scenarios.halting_car_v1.HaltingCarV1Env`.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import AECEnv

from scenarios.env import env_metadata, revised_manual
from scenarios.halting_car_reactive import ReactiveHaltingCar
from scenarios.halting_car_v0 import HaltingCarEnv

DESCRIPTION = """Halting Car v1: the leader's braking is observed, its follower's reaction is not.

    ## Description
    As v0, with two changes to the expert (`scenarios.halting_car_reactive`): in case `stop` the
    brown leader (`car_1`) starts braking 1.5 to 2.7 s into the episode (deceleration 2.5 to
    5 m/s^2), inside the 3.6 s that a predictor observes (12 steps), then stands 1 to 2 s and
    accelerates back (2 to 3 m/s^2) to its cruising speed; case `go`: it keeps its speed. The
    green follower (`car_0`) applies the Intelligent Driver Model towards the leader with a
    reaction delay of 0.6 or 0.9 s (its action at step t is the IDM action for the scene at
    step t - delay), a time headway of 1.3 to 1.9 s and a desired speed 1.1 to 1.3 x the
    leader's cruise. `car_2` ... `car_21` are distractors driving straight at constant speed on
    lanes 0 and 3. All randomness comes from the reset seed; the ranges are the fields of
    `scenarios.ReactiveHaltingCarConfig` (the `config` argument takes one).
"""
HISTORY = """## Version History
    - v1: braking onset inside the observed window; follower reaction delay; headway 1.3-1.9 s.
    - v0: first version.
    """


CHANGES = {
    "so that\n      the leader's stop falls in the predicted part": "so that\n      the leader's "
    "braking onset is observed and the follower's reaction is not",
    "`scenarios.rollout(HaltingCar(),": "`scenarios.rollout(ReactiveHaltingCar(),",
    "| HaltingCarConfig   |": "| ReactiveHaltingCarConfig |",
}


class HaltingCarV1Env(HaltingCarEnv):
    __doc__ = revised_manual(HaltingCarEnv.__doc__, DESCRIPTION, HISTORY, CHANGES)

    scenario_class = ReactiveHaltingCar
    metadata = env_metadata("halting_car_v1", ReactiveHaltingCar)


raw_env = HaltingCarV1Env  # the unwrapped parallel environment


def parallel_env(**kwargs: Any) -> HaltingCarV1Env:
    """The Halting Car v1 parallel environment (see `HaltingCarV1Env` for the arguments)."""
    return HaltingCarV1Env(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """Halting Car v1 with the AEC API (agents act in turn, `parallel_to_aec`)."""
    return parallel_to_aec(HaltingCarV1Env(**kwargs))
