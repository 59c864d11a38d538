"""Halting Car v3 as a PettingZoo environment: `parallel_env()`, `env()` (AEC) and `raw_env`.

The user manual is the docstring of `HaltingCarV3Env`, built from v2's (spaces, rewards, episode
end, infos and arguments are unchanged) with v3's description and version history:
`python -m pydoc scenarios.halting_car_v3.HaltingCarV3Env`.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import AECEnv

from scenarios.env import env_metadata, revised_manual
from scenarios.halting_car_fixed_brake import FixedBrakeHaltingCar
from scenarios.halting_car_v2 import HaltingCarV2Env

DESCRIPTION = """Halting Car v3: the leader's observed braking tells the follower's reaction.

    ## Description
    As v2, with a fixed braking deceleration and a narrower cruising speed
    (`scenarios.halting_car_fixed_brake`): the brown leader (`car_1`) cruises at 9 to 11 m/s;
    in case `stop` it starts braking 2.4 to 3.0 s into the episode at 4 m/s^2, so the last one
    to three of the 12 observed steps (3.6 s) show it, then stands 1.5 s and accelerates back
    at 2.5 m/s^2 to its cruising speed; case `go`: it keeps its speed. The green follower
    (`car_0`) applies the Intelligent Driver Model towards the leader with a reaction delay of
    0.9 s (its action at step t is the IDM action for the scene at step t - 3), so it brakes
    only after the observed window; time headway 1.3 to 1.9 s, desired speed 1.1 to 1.3 x the
    leader's cruise. `car_2` ... `car_21` are distractors driving straight at constant speed on
    lanes 0 and 3. All randomness comes from the reset seed; the ranges are the fields of
    `scenarios.FixedBrakeHaltingCarConfig` (the `config` argument takes one).
"""
HISTORY = """## Version History
    - v3: braking deceleration fixed at 4 m/s^2; cruising speed 9-11 m/s.
    - v2: braking onset late in the observed window; reaction delay 0.9 s; stop and resume fixed.
    - v1: braking onset inside the observed window; follower reaction delay; headway 1.3-1.9 s.
    - v0: first version.
    """


CHANGES = {
    "`scenarios.rollout(LateBrakeHaltingCar(),": "`scenarios.rollout(FixedBrakeHaltingCar(),",
    "| LateBrakeHaltingCarConfig |": "| FixedBrakeHaltingCarConfig |",
}


class HaltingCarV3Env(HaltingCarV2Env):
    __doc__ = revised_manual(HaltingCarV2Env.__doc__, DESCRIPTION, HISTORY, CHANGES)

    scenario_class = FixedBrakeHaltingCar
    metadata = env_metadata("halting_car_v3", FixedBrakeHaltingCar)


raw_env = HaltingCarV3Env  # the unwrapped parallel environment


def parallel_env(**kwargs: Any) -> HaltingCarV3Env:
    """The Halting Car v3 parallel environment (see `HaltingCarV3Env` for the arguments)."""
    return HaltingCarV3Env(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """Halting Car v3 with the AEC API (agents act in turn, `parallel_to_aec`)."""
    return parallel_to_aec(HaltingCarV3Env(**kwargs))
