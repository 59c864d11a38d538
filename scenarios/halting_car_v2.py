"""Halting Car v2 as a PettingZoo environment: `parallel_env()`, `env()` (AEC) and `raw_env`.

The user manual is the docstring of `HaltingCarV2Env`, built from v1's (spaces, rewards, episode
end, infos and arguments are unchanged) with v2's description and version history:
`python -m pydoc scenarios.halting_car_v2.HaltingCarV2Env`.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import AECEnv

from scenarios.env import env_metadata, revised_manual
from scenarios.halting_car_late import LateBrakeHaltingCar
from scenarios.halting_car_v1 import HaltingCarV1Env

DESCRIPTION = """Halting Car v2: only the leader's observed braking tells the follower's reaction.

    ## Description
    As v1, with other ranges (`scenarios.halting_car_late`): in case `stop` the brown leader
    (`car_1`) starts braking 2.4 to 3.0 s into the episode (deceleration 2.5 to 5 m/s^2), so
    the last one to three of the 12 observed steps (3.6 s) show it, then stands 1.5 s and
    accelerates back at 2.5 m/s^2 to its cruising speed; case `go`: it keeps its speed. The
    green follower (`car_0`) applies the Intelligent Driver Model towards the leader with a
    reaction delay of 0.9 s (its action at step t is the IDM action for the scene at step
    t - 3), so it brakes only after the observed window; time headway 1.3 to 1.9 s, desired
    speed 1.1 to 1.3 x the leader's cruise. `car_2` ... `car_21` are distractors driving
    straight at constant speed on lanes 0 and 3. All randomness comes from the reset seed; the
    ranges are the fields of `scenarios.LateBrakeHaltingCarConfig` (the `config` argument
    takes one).
"""
HISTORY = """## Version History
    - v2: braking onset late in the observed window; reaction delay 0.9 s; stop and resume fixed.
    - v1: braking onset inside the observed window; follower reaction delay; headway 1.3-1.9 s.
    - v0: first version.
    """


CHANGES = {
    "`scenarios.rollout(ReactiveHaltingCar(),": "`scenarios.rollout(LateBrakeHaltingCar(),",
    "| ReactiveHaltingCarConfig |": "| LateBrakeHaltingCarConfig |",
}


class HaltingCarV2Env(HaltingCarV1Env):
    __doc__ = revised_manual(HaltingCarV1Env.__doc__, DESCRIPTION, HISTORY, CHANGES)

    scenario_class = LateBrakeHaltingCar
    metadata = env_metadata("halting_car_v2", LateBrakeHaltingCar)


raw_env = HaltingCarV2Env  # the unwrapped parallel environment


def parallel_env(**kwargs: Any) -> HaltingCarV2Env:
    """The Halting Car v2 parallel environment (see `HaltingCarV2Env` for the arguments)."""
    return HaltingCarV2Env(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """Halting Car v2 with the AEC API (agents act in turn, `parallel_to_aec`)."""
    return parallel_to_aec(HaltingCarV2Env(**kwargs))
