"""B scenes of a scenario version stepped at once for RL: the PettingZoo environment's rules
(`scenarios.scenes`) in the shape of Gymnasium's vector environments, per agent.

    env = scenarios.halting_car_v3.vector_env(num_envs=256)
    observations, infos = env.reset(seed=0)          # observations["car_0"]: (256, 109)
    for _ in range(1000):
        observations, rewards, terminations, truncations, infos = env.step(env.expert_actions())

Every value is a dict keyed by agent (`car_0` ... `car_21`, as the PettingZoo environment) of
arrays with a leading scene axis: observations (B, D) float32, rewards (B,) float64,
terminations and truncations (B,) bool, and infos[agent] a dict of (B,) arrays (`role`,
`attention`, `interaction`, `collided`, `off_road`, and the masks `live` and `reset`, below).
Actions come the same way (agent -> (B, 2)) or as one (B, N, 2) array.

Agents that leave: a car that collides or leaves the road terminates and is removed from its
scene, as in the PettingZoo environment; from the next step on, its entries in that scene are
filler (zero observation, reward 0, not terminated or truncated) and its actions are ignored.
`infos[agent]["live"]` says where an entry is real: the agent acted in that step, or its scene
has just started a new episode.

Autoreset (Gymnasium's `AutoresetMode.NEXT_STEP`): a scene whose agents are all done (every car
terminated, or the episode truncated after `max_cycles` steps) starts its next episode at the
next `step` call, which ignores that scene's actions and returns the new episode's first
observation, rewards 0, no termination or truncation, and `infos[agent]["reset"]` set for it.
Its seed is the next of the scene's seed sequence and its case the env's `case` for that scene,
exactly as a PettingZoo environment's `reset()` without arguments after `reset(seed=...)`.

Scene b of `reset(seed=s)` plays seed s + b (a list gives each scene its seed), so the vector
environment reproduces, scene by scene, B PettingZoo environments reset with those seeds
(tested), and the dataset generator's `rollout` with expert actions.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from carlo_lite import World
from scenarios.base import ScenarioConfig
from scenarios.env import EpisodeSeeds, action_array, reset_case
from scenarios.frames import render_scene
from scenarios.registry import resolve
from scenarios.scenes import RewardWeights, Scenes, action_bounds, observation_bounds
from scenarios.versioning import ScenarioVersion


class ScenarioVectorEnv:
    """B scenes of one scenario version (see the module docstring).

    Arguments:
        version: a `ScenarioVersion` or a name (`"halting_car_v3"`; a bare family name is its
            latest version).
        num_envs: B, the number of scenes (at least 1).
        case: the case each scene plays when `reset` gets no option and after every autoreset:
            one for all scenes or one per scene (default: the scenario's major case).
        max_cycles: steps before truncation (default: the scenario's episode length).
        config: the scenario configuration (default: the version's).
        speed_reward_weight, collision_reward, off_road_reward: as the PettingZoo environment.
    """

    metadata: dict[str, Any] = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(
        self,
        version: ScenarioVersion | str,
        num_envs: int,
        *,
        case: str | Sequence[str] | None = None,
        max_cycles: int | None = None,
        config: ScenarioConfig | None = None,
        speed_reward_weight: float = 0.1,
        collision_reward: float = -1.0,
        off_road_reward: float = -1.0,
    ) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer of at least 1, got {num_envs!r}")
        self.version = resolve(version, stacklevel=3) if isinstance(version, str) else version
        self.scenario = self.version.make(config)
        self.config = self.scenario.config
        self.num_envs = num_envs
        self.default_cases = self._cases(case, self.scenario.default_major_case)
        self.max_cycles = self.config.num_steps if max_cycles is None else int(max_cycles)
        if self.max_cycles < 1:
            raise ValueError(f"max_cycles must be at least 1, got {max_cycles}")
        self.rewards = RewardWeights(
            float(speed_reward_weight), float(collision_reward), float(off_road_reward)
        )
        num_cars = self.scenario.num_cars
        self.possible_agents = [f"car_{index}" for index in range(num_cars)]
        self.agents = self.possible_agents[:]  # every agent has a row in every scene
        low, high = observation_bounds(self.scenario)
        self._single_observation_space = spaces.Box(low, high, dtype=np.float32)
        self._single_action_space = spaces.Box(*action_bounds(self.config), dtype=np.float32)
        self._observation_space = batch_space(self._single_observation_space, num_envs)
        self._action_space = batch_space(self._single_action_space, num_envs)
        self._roles = {
            agent: _readonly(np.full(num_envs, role))
            for agent, role in zip(self.possible_agents, self.scenario.role_labels)
        }
        self.scenes: Scenes | None = None
        self.cases: list[str] = list(self.default_cases)
        self.episode_seeds = np.zeros(num_envs, dtype=np.int64)
        self._seeds = [EpisodeSeeds() for _ in range(num_envs)]
        self._cycles = np.zeros(num_envs, dtype=np.int64)
        self._live = np.zeros((num_envs, num_cars), dtype=bool)  # acts in the next step
        self._done = np.zeros(num_envs, dtype=bool)  # restarts at the next step

    # --- spaces ----------------------------------------------------------------------------------
    def single_observation_space(self, agent: str) -> spaces.Box:
        """One scene's observation space of `agent`, (D,)."""
        return self._single_observation_space

    def single_action_space(self, agent: str) -> spaces.Box:
        """One scene's action space of `agent`, (2,)."""
        return self._single_action_space

    def observation_space(self, agent: str) -> spaces.Box:
        """`agent`'s observations over the scenes, (B, D)."""
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Box:
        """`agent`'s actions over the scenes, (B, 2)."""
        return self._action_space

    @property
    def live(self) -> np.ndarray:
        """(B, N) bool: the agents that act in the next step (a done scene's are all live
        again once it restarts)."""
        return self._live.copy()

    # --- episodes --------------------------------------------------------------------------------
    def reset(
        self, seed: int | Sequence[int] | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, np.ndarray]]]:
        """Start an episode in every scene. `seed`: an int s gives scene b seed s + b, a list
        one seed per scene, None each scene's next seed. `options={"case": ...}`: the case of
        these episodes, one for all scenes or one per scene (default: the env's `case`)."""
        seeds = self._reset_seeds(seed)
        cases = self._cases(reset_case(options, self.default_cases), None)
        plans = []
        for scene, (scene_seed, case) in enumerate(zip(seeds, cases)):
            self.episode_seeds[scene] = self._seeds[scene].next(scene_seed)
            plans.append(self.scenario.plan(int(self.episode_seeds[scene]), case))
        self.cases = list(cases)
        every = np.arange(self.num_envs)
        if self.scenes is None:
            self.scenes = Scenes(self.scenario, plans)
        else:
            self.scenes.restart(every, plans)
        self.scenes.update()
        self._cycles[:] = 0
        self._live[:] = True
        self._done[:] = False
        no_flags = np.zeros_like(self._live)
        started = np.ones(self.num_envs, dtype=bool)
        infos = self._infos(no_flags, no_flags, self._live, started)
        return self._per_agent_rows(self.scenes.observations()), infos

    def step(
        self, actions: Mapping[str, Any] | np.ndarray
    ) -> tuple[dict, dict, dict, dict, dict[str, dict[str, np.ndarray]]]:
        """Apply one action per agent and scene (ignored where the agent is not live or its
        scene restarts), held for `record_every` simulation steps; done scenes restart.

        Raises (before anything moves) ValueError naming the agent, and the scene where it
        matters, for actions that are not finite (B, 2) real numbers where the agent is live.
        """
        if self.scenes is None:
            raise RuntimeError("call reset() before step()")
        restarting = self._done.copy()
        acting = self._live & ~restarting[:, None]  # (B, N)
        controls = self._controls(actions, acting)
        collided, off_road = self.scenes.advance(controls)
        collided &= acting
        off_road &= acting
        self._cycles += 1
        if restarting.any():
            self._restart(np.nonzero(restarting)[0])
        self.scenes.update()
        terminated = collided | off_road
        truncated = (self._cycles >= self.max_cycles)[:, None] & acting
        rewards = self.scenes.rewards(collided, off_road, self.rewards)
        rewards[~acting] = 0.0
        observations = self.scenes.observations()  # (N, B, D)
        shown = acting | restarting[:, None]
        observations[~shown.T] = 0.0
        self._live = np.where(restarting[:, None], True, acting & ~terminated & ~truncated)
        self._done = ~self._live.any(axis=1)
        infos = self._infos(collided, off_road, shown, restarting)
        return (
            self._per_agent_rows(observations),
            self._per_agent(rewards),
            self._per_agent(terminated),
            self._per_agent(truncated),
            infos,
        )

    def _restart(self, scenes: np.ndarray) -> None:
        """Next episodes in `scenes`: each scene's next seed, its default case."""
        plans = []
        for scene in scenes.tolist():
            self.episode_seeds[scene] = self._seeds[scene].next(None)
            self.cases[scene] = self.default_cases[scene]
            plans.append(self.scenario.plan(int(self.episode_seeds[scene]), self.cases[scene]))
        self.scenes.restart(scenes, plans)
        self._cycles[scenes] = 0

    def expert_actions(self) -> dict[str, np.ndarray]:
        """The expert's actions, agent -> (B, 2) float32 (merge in your own)."""
        if self.scenes is None:
            raise RuntimeError("call reset() before expert_actions()")
        return self._per_agent(self.scenes.expert_actions())

    # --- arguments -------------------------------------------------------------------------------
    def _cases(self, case: Any, default: str | None) -> list[str]:
        """One checked case per scene from a case, a sequence of B cases, or None (default)."""
        if case is None:
            case = default
        if isinstance(case, str):
            cases = [case] * self.num_envs
        elif isinstance(case, Sequence) and len(case) == self.num_envs:
            cases = list(case)
        else:
            raise ValueError(f"case must be one case or {self.num_envs} cases, got {case!r}")
        return [self.scenario.check_case(item) for item in cases]

    def _reset_seeds(self, seed: int | Sequence[int] | None) -> list[int | None]:
        if seed is None:
            return [None] * self.num_envs
        if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            return [int(seed) + scene for scene in range(self.num_envs)]
        if isinstance(seed, Sequence) and len(seed) == self.num_envs:
            return [int(value) for value in seed]
        raise ValueError(f"seed must be an int, {self.num_envs} ints or None, got {seed!r}")

    def _controls(self, actions: Mapping[str, Any] | np.ndarray, acting: np.ndarray) -> np.ndarray:
        """(B, N, 2) controls; every acting (scene, agent) needs 2 finite real numbers."""
        shape = (self.num_envs, len(self.possible_agents), 2)
        if isinstance(actions, np.ndarray):
            if actions.shape != shape or actions.dtype.kind not in "iuf":
                raise ValueError(f"actions must be a real {shape} array or a dict of (B, 2)")
            controls = actions.astype(float)
        elif isinstance(actions, Mapping):
            controls = self._stack(actions)
        else:
            raise TypeError(
                f"actions must be a dict {{agent: (B, 2) array}} or a {shape} array, "
                f"got {type(actions).__name__}"
            )
        bad = ~np.isfinite(controls).all(axis=2) & acting
        if bad.any():
            scene, car = np.argwhere(bad)[0].tolist()
            action_array(self.possible_agents[car], controls[scene, car], f"in scene {scene}")
        return np.where(acting[..., None], controls, 0.0)

    def _stack(self, actions: Mapping[str, Any]) -> np.ndarray:
        missing = [agent for agent in self.possible_agents if agent not in actions]
        unknown = sorted(set(actions) - set(self.possible_agents), key=str)
        if missing or unknown:
            problems = {"missing": missing, "unknown agents": unknown}
            raise ValueError(
                "actions must name every agent (env.possible_agents), each with a (B, 2) array; "
                + "; ".join(f"{what} {names}" for what, names in problems.items() if names)
            )
        rows = []
        for agent in self.possible_agents:
            array = np.asarray(actions[agent])
            if array.dtype.kind not in "iuf" or array.shape != (self.num_envs, 2):
                problem = f"dtype {array.dtype}" if array.dtype.kind not in "iuf" else array.shape
                raise ValueError(
                    f"action of {agent} must be a ({self.num_envs}, 2) array of real numbers "
                    f"[steering rad, acceleration m/s^2], one row per scene; got {problem}"
                )
            rows.append(array)
        return np.stack(rows, axis=1).astype(float)  # (B, N, 2)

    # --- results ---------------------------------------------------------------------------------
    def _per_agent(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """(B, N, ...) -> {agent: (B, ...)} (views)."""
        return {agent: values[:, index] for index, agent in enumerate(self.possible_agents)}

    def _per_agent_rows(self, values: np.ndarray) -> dict[str, np.ndarray]:
        """(N, B, ...) -> {agent: (B, ...)} (contiguous views)."""
        return dict(zip(self.possible_agents, values))

    def _infos(
        self, collided: np.ndarray, off_road: np.ndarray, shown: np.ndarray, reset: np.ndarray
    ) -> dict[str, dict[str, np.ndarray]]:
        attention, interaction = self.scenes.labels()  # (B, N), (B,)
        return {
            agent: {
                "role": self._roles[agent],
                "attention": attention[:, index],
                "interaction": interaction,
                "collided": collided[:, index],
                "off_road": off_road[:, index],
                "live": shown[:, index],
                "reset": reset,
            }
            for index, agent in enumerate(self.possible_agents)
        }

    def render(self, scene: int = 0) -> np.ndarray:
        """A top-down uint8 frame of `scene`, as the PettingZoo environment's
        (`scenarios.frames`): (200, 800, 3) following its main cars on the straight road,
        (400, 400, 3) centred on the junction on a layout."""
        if self.scenes is None:
            raise RuntimeError("call reset() before render()")
        return render_scene(self.scenario, World.from_scene(self.scenes.world, scene))

    def close(self) -> None:
        """Nothing to release (no window); for the Gymnasium interface."""


def _readonly(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array
