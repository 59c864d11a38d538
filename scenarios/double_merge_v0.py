"""Double Merge as a PettingZoo environment: `parallel_env()`, `env()` (AEC) and `raw_env`.

The user manual (observation and action spaces with shapes, units and bounds, rewards, episode
end, infos, arguments) is the docstring of `DoubleMergeEnv` below:
`python -m pydoc scenarios.double_merge_v0.DoubleMergeEnv`.
"""

from __future__ import annotations

from typing import Any

from pettingzoo.utils.conversions import parallel_to_aec
from pettingzoo.utils.env import AECEnv

from scenarios.double_merge import DoubleMerge
from scenarios.env import ScenarioParallelEnv, env_metadata


class DoubleMergeEnv(ScenarioParallelEnv):
    """Two main cars in the two inner lanes of a 4-lane road swap lanes; 20 distractors.

    ## Description
    The green car (`car_0`, lane 2) and the brown car (`car_1`, lane 1) want each other's lane.
    The front one changes lane at a random time; the rear one moves next to the centre line and
    waits until it sees the front car settled in the target lane, then merges after a random
    reaction delay. `car_2` ... `car_21` are distractors driving straight at constant speed on
    lanes 0 and 3 (a random speed per lane). Case `major`: the green car starts behind the brown
    car; case `minor`: ahead of it. All randomness comes from the reset seed; the ranges are the
    fields of `scenarios.DoubleMergeConfig`.

    ## Action Space
    `Box([-0.5, -8.0], [0.5, 4.0], (2,), float32)` per agent: steering angle [rad] (positive
    turns left) and acceleration [m/s^2]. An action is held for one env step = 2 simulation
    steps of 0.1 s (0.2 s). Speeds stay in [0, 40] m/s.
    Values outside the bounds are clipped. `step` takes a dict with an action for exactly the
    live agents (`env.agents`); an action that is not 2 finite real numbers (a string, NaN,
    another shape) raises a ValueError naming the agent, before anything moves.
    `env.unwrapped.expert_actions()` gives the expert's action for every live agent, so you can
    drive some cars yourself and let the expert drive the rest.

    ## Observation Space
    `Box(float32, (109,))` per agent: its own state, then for each other car in agent order
    (`car_0`, `car_1`, ..., skipping itself) a presence flag and its state relative to the ego
    car. Removed cars have presence 0 and zeros. Values are clipped to the bounds.

    | Index           | Observation                                   | Min    | Max   |
    |-----------------|-----------------------------------------------|--------|-------|
    | 0               | ego x along the road [m]                      | 0      | 600   |
    | 1               | ego y across the road [m] (lane i: 3.5 i..)   | 0      | 14    |
    | 2               | ego heading [rad] (0 = along the road)        | -pi    | pi    |
    | 3               | ego speed [m/s]                               | 0      | 40    |
    | 4 + 5k          | other car k present (1) or removed (0)        | 0      | 1     |
    | 5 + 5k          | other car k: x - ego x [m]                    | -600   | 600   |
    | 6 + 5k          | other car k: y - ego y [m]                    | -14    | 14    |
    | 7 + 5k          | other car k: heading - ego heading [rad]      | -pi    | pi    |
    | 8 + 5k          | other car k: speed - ego speed [m/s]          | -40    | 40    |

    with k = 0 ... 20 indexing the other 21 cars.

    ## Rewards
    Per agent and step: `speed_reward_weight * v cos(heading) / 40` (forward progress, at most
    0.1 by default), plus `collision_reward` (-1) if it collided and `off_road_reward` (-1) if
    any part of it left the road during the step.

    ## Starting State
    Main cars on their lane centres, heading 0, at a common random cruising speed (8 to 12 m/s,
    +-0.3 m/s); the rear one at x in [50, 70] m, the front one 10 to 18 m ahead. Distractors:
    10 per outer lane, 9 to 20 m apart, the rearmost at x in [0, 20] m.

    ## Episode End
    - Termination (per agent): it collided with another car or left the road (checked every
      0.1 s). The car is then removed from the world and from `agents` for good.
    - Truncation (all agents): after `max_cycles` steps (default 60 = 12 s, the scenario's
      episode length; suggested split for prediction: 15 observed + 45 predicted steps).

    ## Infos
    Each agent's info: `role` ("main_green", "main_brown" or "distractor"), `attention` (index of
    the car it reacts to, -1 for none: the main cars attend to each other, the paper's "Correct"
    oracle), `interaction` (the rear main car is waiting next to the centre line), `collided`,
    `off_road`.

    ## Arguments
    | Parameter             | Type               | Default   | Description                     |
    |-----------------------|--------------------|-----------|---------------------------------|
    | `case`                | str                | "major"   | case when reset gets no option  |
    | `max_cycles`          | int                | 60        | steps before truncation         |
    | `render_mode`         | str                | None      | "rgb_array" or "human"          |
    | `config`              | DoubleMergeConfig  | default   | timings, ranges, road, limits   |
    | `speed_reward_weight` | float              | 0.1       | weight of the progress reward   |
    | `collision_reward`    | float              | -1.0      | reward on collision             |
    | `off_road_reward`     | float              | -1.0      | reward on leaving the road      |

    `reset(seed=..., options={"case": "minor"})` picks the case of one episode ("case" is the
    only option; any other key is ignored with a UserWarning). With a seed,
    stepping every agent with `expert_actions()` reproduces `scenarios.rollout(DoubleMerge(),
    seed, case)` exactly; without one, `env.unwrapped.episode_seed` says which seed was used.

    ## Version History
    - v0: first version.
    """

    scenario_class = DoubleMerge
    metadata = env_metadata("double_merge_v0", DoubleMerge)


raw_env = DoubleMergeEnv  # the unwrapped parallel environment


def parallel_env(**kwargs: Any) -> DoubleMergeEnv:
    """The Double Merge parallel environment (see `DoubleMergeEnv` for the arguments)."""
    return DoubleMergeEnv(**kwargs)


def env(**kwargs: Any) -> AECEnv:
    """The Double Merge environment with the AEC API (agents act in turn, `parallel_to_aec`)."""
    return parallel_to_aec(DoubleMergeEnv(**kwargs))
