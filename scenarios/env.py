"""A thin PettingZoo `ParallelEnv` adapter over a scenario (shared by both `_v0` modules).

The environment owns a scenario and its `carlo_lite.World`; every call is a few vectorised numpy
operations over all cars, then dicts keyed by agent name. Stepping it with
`expert_actions()` for every agent reproduces `scenarios.rollout` exactly (same seed, same case),
because both step the world through `scenarios.rollout.advance`.
"""

from __future__ import annotations

import reprlib
import warnings
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from carlo_lite import render_rgb
from scenarios.base import Scenario, ScenarioConfig
from scenarios.rollout import advance

EGO_FEATURES = 4  # x, y, heading, speed
OTHER_FEATURES = 5  # presence, dx, dy, d_heading, d_speed
FRAME_WIDTH_PX, FRAME_HEIGHT_PX = 800, 200
RENDER_MODES = ("human", "rgb_array")
# PettingZoo's API checkers (api_test, parallel_api_test) call reset(seed=0, options={"options": 1})
# only to see that reset takes these keywords: reset accepts and ignores this one key silently.
CHECKER_PROBE_OPTION = "options"


def observation_bounds(config: ScenarioConfig, num_cars: int) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper bounds (D,) of one agent's observation; D = 4 + 5 (N - 1)."""
    length, width = config.road_length_m, config.num_lanes * config.lane_width_m
    top_speed = config.limits.max_speed_mps
    ego_low = [0.0, 0.0, -np.pi, 0.0]
    ego_high = [length, width, np.pi, top_speed]
    other_low = [0.0, -length, -width, -np.pi, -top_speed]
    other_high = [1.0, length, width, np.pi, top_speed]
    low = np.array(ego_low + other_low * (num_cars - 1), dtype=np.float32)
    high = np.array(ego_high + other_high * (num_cars - 1), dtype=np.float32)
    return low, high


def _action_array(agent: str, action: Any) -> np.ndarray:
    """`action` as a float (2,) array; a ValueError naming `agent` and the problem unless it is
    two finite real numbers (strings, booleans and complex numbers are refused, not converted)."""
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
        f"action of {agent} must be 2 finite numbers [steering rad, acceleration m/s^2], "
        f"shape (2,); got {reprlib.repr(action)}: {problem}"
    )


def revised_manual(
    manual: str, description: str, history: str, changes: Mapping[str, str] = {}
) -> str:
    """A new version's user manual from the previous version's class docstring: its own
    `description` (title and "## Description" section) and `history` ("## Version History"
    section), the sections in between kept with the exact text `changes` (old -> new) made.
    Raises ValueError if a changed text is not in the old manual (so the two cannot drift)."""
    body = manual[manual.index("## Action Space") : manual.index("## Version History")]
    for old, new in changes.items():
        if old not in body:
            raise ValueError(f"the previous manual has no {old!r}: update the new version's")
        body = body.replace(old, new)
    return description.rstrip() + "\n\n    " + body + history


def env_metadata(name: str, scenario_class: type[Scenario]) -> dict[str, Any]:
    """Class-level PettingZoo metadata of a scenario env: one frame per env step of the
    scenario's default configuration (instances recompute render_fps from their own config)."""
    return {
        "name": name,
        "render_modes": list(RENDER_MODES),
        "render_fps": 1.0 / scenario_class.config_class().recorded_dt,
        "is_parallelizable": True,
    }


class ScenarioParallelEnv(ParallelEnv):
    """Base class of the scenario environments; see `DoubleMergeEnv` / `HaltingCarEnv` for the
    user manual (observation table, actions, rewards, episode end, arguments)."""

    scenario_class: ClassVar[type[Scenario]]
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
        self.scenario = self.scenario_class(config)
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
        self.speed_reward_weight = float(speed_reward_weight)
        self.collision_reward = float(collision_reward)
        self.off_road_reward = float(off_road_reward)

        num_cars = self.scenario.num_cars
        self.possible_agents = [f"car_{index}" for index in range(num_cars)]
        self.agent_index = {agent: index for index, agent in enumerate(self.possible_agents)}
        low, high = observation_bounds(self.config, num_cars)
        self._obs_low, self._obs_high = low, high
        limits = self.config.limits
        action_low = np.array([-limits.max_steer_rad, -limits.max_decel_mps2], dtype=np.float32)
        action_high = np.array([limits.max_steer_rad, limits.max_accel_mps2], dtype=np.float32)
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
        # every car's observation lists the others in agent order, skipping itself: (N, N-1)
        everyone = np.arange(num_cars)
        self._others = np.array([np.delete(everyone, index) for index in everyone])
        self.agents: list[str] = []
        self.world = None
        self.case: str | None = None
        self.episode_seed: int | None = None
        self.num_cycles = 0
        self._seed_rng: np.random.Generator | None = None
        self._viewer = None

    # --- spaces ----------------------------------------------------------------------------------
    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> spaces.Box:
        return self._action_spaces[agent]

    # --- episode ---------------------------------------------------------------------------------
    def _next_episode_seed(self, seed: int | None) -> int:
        """`seed` itself if given; otherwise the next seed of a sequence started by the last
        explicit seed (or by fresh entropy), so `rollout(.., episode_seed, ..)` can replay it."""
        if seed is not None:
            self._seed_rng = np.random.default_rng(seed)
            return int(seed)
        if self._seed_rng is None:
            self._seed_rng = np.random.default_rng()
        return int(self._seed_rng.integers(0, 2**63 - 1))

    def reset(
        self, seed: int | None = None, options: Mapping[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode; `options={"case": ...}` picks the case (default: the env's case).

        Any other option key is ignored with a UserWarning (a typo such as "cse" would otherwise
        silently play the default case), except PettingZoo's checker probe `{"options": 1}`.
        """
        if options is not None and not isinstance(options, Mapping):
            raise TypeError(f"options must be a dict such as {{'case': ...}}, got {options!r}")
        options = dict(options or {})
        options.pop(CHECKER_PROBE_OPTION, None)
        case = self.scenario.check_case(options.pop("case", self.default_case))
        if options:
            warnings.warn(
                f"reset ignores unknown options {sorted(options, key=str)}; the only one is 'case'",
                stacklevel=2,
            )
        self.episode_seed = self._next_episode_seed(seed)
        self.case = case
        self.world = self.scenario.reset(np.random.default_rng(self.episode_seed), case)
        self.scenario.update(self.world)
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
            controls[self.agent_index[agent]] = _action_array(agent, action)
        return controls

    def step(self, actions: Mapping[str, Any]) -> tuple[dict, dict, dict, dict, dict]:
        """Apply one action per live agent, held for `record_every` simulation steps.

        Raises (before anything moves) a ValueError that names the agent for an action that is
        not 2 finite numbers, or the agents for a dict that does not cover exactly `agents`.
        """
        if self.world is None:
            raise RuntimeError("call reset() before step()")
        controls = self._controls(actions)
        live = self.agents
        collided, off_road = advance(
            self.world, controls, self.config.record_every, remove_crashed=True
        )
        self.num_cycles += 1
        self.scenario.update(self.world)
        truncated = self.num_cycles >= self.max_cycles
        observations = self._observations(live)
        rewards = self._rewards(live, collided, off_road)
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
        if self.world is None:
            raise RuntimeError("call reset() before expert_actions()")
        controls = self.scenario.expert_actions(self.world)  # (N, 2) float32
        return {agent: controls[self.agent_index[agent]] for agent in self.agents}

    # --- observations, rewards, infos -----------------------------------------------------------
    def _observation_array(self) -> np.ndarray:
        """(N, D) float32: ego state, then the others' relative states in agent order."""
        state = self.world.state  # (N, 4)
        active = self.world.active  # (N,)
        others = self._others  # (N, N-1)
        relative = state[others] - state[:, None, :]  # (N, N-1, 4)
        relative[..., 2] = (relative[..., 2] + np.pi) % (2.0 * np.pi) - np.pi
        present = active[others]  # (N, N-1)
        relative *= present[..., None]
        block = np.concatenate([present[..., None], relative], axis=2)  # (N, N-1, 5)
        flat = np.concatenate([state, block.reshape(len(state), -1)], axis=1)  # (N, D)
        return np.clip(flat, self._obs_low, self._obs_high).astype(np.float32)

    def _observations(self, agents: list[str]) -> dict[str, np.ndarray]:
        rows = self._observation_array()
        return {agent: rows[self.agent_index[agent]] for agent in agents}

    def _rewards(
        self, agents: list[str], collided: np.ndarray, off_road: np.ndarray
    ) -> dict[str, float]:
        forward = self.world.speed * np.cos(self.world.heading)  # (N,) [m/s]
        reward = (
            self.speed_reward_weight * forward / self.config.limits.max_speed_mps
            + self.collision_reward * collided
            + self.off_road_reward * off_road
        )  # (N,)
        return {agent: float(reward[self.agent_index[agent]]) for agent in agents}

    def _infos(
        self, agents: list[str], collided: np.ndarray, off_road: np.ndarray
    ) -> dict[str, dict[str, Any]]:
        labels = self.scenario.attention_labels(self.world)  # (N,)
        interaction = bool(self.scenario.interaction(self.world))
        roles = self.scenario.role_labels
        infos = {}
        for agent in agents:
            index = self.agent_index[agent]
            infos[agent] = {
                "role": roles[index],
                "attention": int(labels[index]),
                "interaction": interaction,
                "collided": bool(collided[index]),
                "off_road": bool(off_road[index]),
            }
        return infos

    def state(self) -> np.ndarray:
        """Global state (N, 4) float32 [x, y, heading, speed] of every car (removed ones frozen)."""
        return np.clip(self.world.state, self.state_space.low, self.state_space.high).astype(
            np.float32
        )

    # --- rendering -------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """rgb_array: a (200, 800, 3) uint8 top-down frame centred on the main cars; human: show
        it in a window and return None."""
        if self.render_mode is None:
            warnings.warn("render() called without a render_mode; nothing drawn", stacklevel=2)
            return None
        if self.world is None:
            raise RuntimeError("call reset() before render()")
        main = np.nonzero(self.world.active[:2])[0]
        center = None
        if len(main):
            center = (float(self.world.xy[main, 0].mean()), 0.5 * self.scenario.road.width_m)
        frame = render_rgb(self.world, FRAME_WIDTH_PX, FRAME_HEIGHT_PX, center_xy=center)
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
