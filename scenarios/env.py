"""A thin PettingZoo `ParallelEnv` over one scene of a scenario version (`scenarios.scenes`).

Each registered version gets its own subclass, whose docstring is its user manual
(`scenarios.manual`), in its environment module (`scenarios.halting_car_v3.raw_env`). Every
call is a few vectorised numpy operations over all cars, then dicts keyed by agent name.
Stepping it with `expert_actions()` for every agent reproduces `scenarios.rollout` exactly
(same seed, same case): both step the same expert and world.
"""

from __future__ import annotations

import reprlib
import warnings
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from carlo_lite import World
from scenarios.base import ScenarioConfig
from scenarios.frames import render_scene
from scenarios.scenes import EGO_FEATURES, RewardWeights, Scenes, action_bounds, observation_bounds
from scenarios.versioning import ScenarioVersion

RENDER_MODES = ("human", "rgb_array")
# PettingZoo's API checkers (api_test, parallel_api_test) call reset(seed=0, options={"options": 1})
# only to see that reset takes these keywords: reset accepts and ignores this one key silently.
CHECKER_PROBE_OPTION = "options"


def action_array(agent: str, action: Any, where: str = "") -> np.ndarray:
    """`action` as a float (2,) array; a ValueError naming `agent` (and `where`, e.g. "in
    scene 3") and the problem unless it is two finite real numbers (strings, booleans and
    complex numbers are refused, not converted)."""
    array = np.asarray(action)
    if array.dtype.kind not in "iuf":
        problem = f"not real numbers (dtype {array.dtype})"
    elif array.shape != (2,):
        problem = f"shape {array.shape}"
    elif not np.isfinite(array).all():
        problem = "non-finite values"
    else:
        return array.astype(float)
    raise ValueError(
        f"action of {agent}{' ' + where if where else ''} must be 2 finite numbers "
        f"[steering rad, acceleration m/s^2], shape (2,); got {reprlib.repr(action)}: {problem}"
    )


def reset_case(options: Mapping[str, Any] | None, default: Any) -> Any:
    """What `reset(options=...)` asks for as its case (`default` without one), unchecked.

    Unknown option keys warn (a typo such as "cse" would otherwise silently play the default
    case), except PettingZoo's checker probe `{"options": 1}`.
    """
    if options is not None and not isinstance(options, Mapping):
        raise TypeError(f"options must be a dict such as {{'case': ...}}, got {options!r}")
    options = dict(options or {})
    options.pop(CHECKER_PROBE_OPTION, None)
    case = options.pop("case", default)
    if options:
        warnings.warn(
            f"reset ignores unknown options {sorted(options, key=str)}; the only one is 'case'",
            stacklevel=3,
        )
    return case


def env_metadata(version: ScenarioVersion) -> dict[str, Any]:
    """Class-level PettingZoo metadata of a version's env: one frame per env step of the
    version's configuration (instances recompute render_fps from their own config)."""
    return {
        "name": version.name,
        "render_modes": list(RENDER_MODES),
        "render_fps": 1.0 / version.config().recorded_dt,
        "is_parallelizable": True,
    }


class EpisodeSeeds:
    """Episode seeds as the environments draw them: a given seed is used as it is and starts a
    sequence; a reset without one takes the sequence's next seed (or fresh entropy's)."""

    def __init__(self) -> None:
        self._rng: np.random.Generator | None = None

    def next(self, seed: int | None) -> int:
        if seed is not None:
            self._rng = np.random.default_rng(seed)
            return int(seed)
        if self._rng is None:
            self._rng = np.random.default_rng()
        return int(self._rng.integers(0, 2**63 - 1))


class ScenarioParallelEnv(ParallelEnv):
    """Base class of the scenario environments; each version's subclass documents itself
    (observation table, actions, rewards, episode end, arguments): `help(raw_env)`."""

    version: ClassVar[ScenarioVersion]
    metadata: ClassVar[dict[str, Any]] = {
        "name": "scenario_v0",
        "render_modes": list(RENDER_MODES),
        "render_fps": 5,
        "is_parallelizable": True,
    }

    def __init__(
        self,
        case: str | None = None,
        max_cycles: int | None = None,
        render_mode: str | None = None,
        config: ScenarioConfig | None = None,
        speed_reward_weight: float = 0.1,
        collision_reward: float = -1.0,
        off_road_reward: float = -1.0,
    ) -> None:
        self.scenario = self.version.make(config)
        self.config = self.scenario.config
        self.default_case = self.scenario.check_case(case or self.scenario.default_major_case)
        self.max_cycles = self.config.num_steps if max_cycles is None else int(max_cycles)
        if self.max_cycles < 1:
            raise ValueError(f"max_cycles must be at least 1, got {max_cycles}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']}")
        self.render_mode = render_mode
        # a new dict for this instance; the class-level metadata is never written to
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.config.recorded_dt}
        self.rewards = RewardWeights(
            float(speed_reward_weight), float(collision_reward), float(off_road_reward)
        )
        num_cars = self.scenario.num_cars
        self.possible_agents = [f"car_{index}" for index in range(num_cars)]
        self.agent_index = {agent: index for index, agent in enumerate(self.possible_agents)}
        low, high = observation_bounds(self.scenario)
        action_low, action_high = action_bounds(self.config)
        self._observation_spaces = {
            agent: spaces.Box(low, high, dtype=np.float32) for agent in self.possible_agents
        }
        self._action_spaces = {
            agent: spaces.Box(action_low, action_high, dtype=np.float32)
            for agent in self.possible_agents
        }
        self.state_space = spaces.Box(
            np.tile(low[:EGO_FEATURES], (num_cars, 1)),
            np.tile(high[:EGO_FEATURES], (num_cars, 1)),
            dtype=np.float32,
        )
        self.agents: list[str] = []
        self.scenes: Scenes | None = None
        self.world: World | None = None  # the scene's world, for reading and rendering
        self.case: str | None = None
        self.episode_seed: int | None = None
        self.num_cycles = 0
        self._seeds = EpisodeSeeds()
        self._viewer = None

    # --- spaces ----------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._action_spaces[agent]

    # --- episode ---------------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode; `options={"case": ...}` picks the case (default: the env's case).

        Any other option key is ignored with a UserWarning (a typo such as "cse" would otherwise
        silently play the default case), except PettingZoo's checker probe `{"options": 1}`.
        """
        case = self.scenario.check_case(reset_case(options, self.default_case))
        self.episode_seed = self._seeds.next(seed)
        self.case = case
        plans = [self.scenario.plan(self.episode_seed, case)]
        if self.scenes is None:
            self.scenes = Scenes(self.scenario, plans)
            self.world = World.of(self.scenes.world)
        else:
            self.scenes.restart(np.zeros(1, dtype=np.int64), plans)
        self.scenes.update()
        self.agents = self.possible_agents[:]
        self.num_cycles = 0
        no_flags = np.zeros(self.scenario.num_cars, dtype=bool)
        observations = self._observations(self.agents)
        infos = self._infos(self.agents, no_flags, no_flags)
        if self.render_mode == "human":
            self.render()
        return observations, infos

    def _controls(self, actions: Mapping[str, Any]) -> np.ndarray:
        """(N, 2) controls from the action dict; every live agent needs a valid action."""
        if not isinstance(actions, Mapping):
            raise TypeError(
                f"actions must be a dict {{agent: action}} for the live agents, "
                f"got {type(actions).__name__}"
            )
        unknown = sorted(set(actions) - set(self.possible_agents), key=str)
        gone = sorted(set(actions) & (set(self.possible_agents) - set(self.agents)))
        missing = sorted(set(self.agents) - set(actions))
        if unknown or gone or missing:
            problems = {"missing": missing, "unknown agents": unknown, "no longer live": gone}
            raise ValueError(
                "actions must be given for exactly the live agents (env.agents); "
                + "; ".join(f"{what} {names}" for what, names in problems.items() if names)
            )
        controls = np.zeros((self.scenario.num_cars, 2))
        for agent, action in actions.items():
            controls[self.agent_index[agent]] = action_array(agent, action)
        return controls

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Apply one action per live agent, held for `record_every` simulation steps.

        Raises (before anything moves) a ValueError that names the agent for an action that is
        not 2 finite numbers, or the agents for a dict that does not cover exactly `agents`.
        """
        if self.scenes is None:
            raise RuntimeError("call reset() before step()")
        controls = self._controls(actions)
        live = self.agents
        collided, off_road = self.scenes.advance(controls[None])
        collided, off_road = collided[0], off_road[0]
        self.num_cycles += 1
        self.scenes.update()
        truncated = self.num_cycles >= self.max_cycles
        observations = self._observations(live)
        reward = self.scenes.rewards(collided[None], off_road[None], self.rewards)[0]  # (N,)
        rewards = {agent: float(reward[self.agent_index[agent]]) for agent in live}
        terminations = {
            agent: bool(collided[index] or off_road[index])
            for agent, index in ((agent, self.agent_index[agent]) for agent in live)
        }
        truncations = dict.fromkeys(live, truncated)
        infos = self._infos(live, collided, off_road)
        self.agents = [agent for agent in live if not (terminations[agent] or truncations[agent])]
        if self.render_mode == "human":
            self.render()
        return observations, rewards, terminations, truncations, infos

    def expert_actions(self) -> dict[str, np.ndarray]:
        """The expert's action, float32 (2,), for every live agent (merge in your own)."""
        if self.scenes is None:
            raise RuntimeError("call reset() before expert_actions()")
        controls = self.scenes.expert_actions()[0]  # (N, 2) float32
        return {agent: controls[self.agent_index[agent]] for agent in self.agents}

    # --- observations, infos ---------------------------------------------------------------------
    def _observations(self, agents: list[str]) -> dict[str, np.ndarray]:
        rows = self.scenes.observations()[:, 0]  # (N, D)
        return {agent: rows[self.agent_index[agent]] for agent in agents}

    def _infos(
        self, agents: list[str], collided: np.ndarray, off_road: np.ndarray
    ) -> dict[str, dict[str, Any]]:
        attention, interaction = self.scenes.labels()
        labels, flag = attention[0], bool(interaction[0])
        roles = self.scenario.role_labels
        infos = {}
        for agent in agents:
            index = self.agent_index[agent]
            infos[agent] = {
                "role": roles[index],
                "attention": int(labels[index]),
                "interaction": flag,
                "collided": bool(collided[index]),
                "off_road": bool(off_road[index]),
            }
        return infos

    def state(self) -> np.ndarray:
        """Global state (N, 4) float32 [x, y, heading, speed] of every car (removed ones frozen)."""
        return self.scenes.state()[0]

    # --- rendering -------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """rgb_array: a top-down uint8 frame, (200, 800, 3) following the main cars on the
        straight road, (400, 400, 3) centred on the junction on a layout
        (`scenarios.frames`); human: show it in a window and return None."""
        if self.render_mode is None:
            warnings.warn("render() called without a render_mode; nothing drawn", stacklevel=2)
            return None
        if self.world is None:
            raise RuntimeError("call reset() before render()")
        frame = render_scene(self.scenario, self.world)
        if self.render_mode == "rgb_array":
            return frame
        if self._viewer is None:
            from carlo_lite import HumanViewer

            self._viewer = HumanViewer(self.metadata["name"], fps=self.metadata["render_fps"])
        self._viewer.show(frame)
        return None

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None

    # --- pickling --------------------------------------------------------------------------------
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state["_viewer"] = None  # a window cannot be pickled; a new one opens on demand
        return state
