"""scenarios.vector_env: B scenes at once give, scene by scene, what B PettingZoo environments
with the same seeds give (observations, rewards, terminations, truncations, infos), through
removed cars, autoresets at different times and mixed cases; seeds, spaces, and bad actions
refused with the single environment's one-line errors, naming the scene and car."""

from __future__ import annotations

import numpy as np
import pytest

from scenarios import ENV_MODULES, FAMILIES, VERSIONS, halting_car_v3
from scenarios.vector_env import ScenarioVectorEnv

INFO_KEYS = ("role", "attention", "interaction", "collided", "off_road")


class Singles:
    """B PettingZoo environments played as the vector environment's scenes should be: reset
    with seeds s + b, reset again without arguments when all their agents are done."""

    def __init__(self, module, cases: list[str], seed: int, max_cycles: int | None = None):
        self.envs = [module.parallel_env(case=case, max_cycles=max_cycles) for case in cases]
        self.first = [env.reset(seed=seed + b) for b, env in enumerate(self.envs)]

    def step(self, b: int, actions: dict) -> tuple[tuple, bool]:
        """Scene b's result for `actions` (rows of its live agents), and whether it reset."""
        env = self.envs[b]
        if not env.agents:
            return env.reset(), True
        live = {agent: actions[agent] for agent in env.agents}
        return env.step(live), False


def assert_scene_equal(vector_result: tuple, single_result: tuple, b: int, reset: bool) -> None:
    """Scene b of a vector step against the single env's step (or reset) result."""
    if reset:
        observations, infos = single_result
        rewards = terminations = truncations = {}
    else:
        observations, rewards, terminations, truncations, infos = single_result
    v_obs, v_rew, v_term, v_trunc, v_infos = vector_result
    for agent in v_obs:
        assert bool(v_infos[agent]["reset"][b]) == reset
        live = agent in observations
        assert bool(v_infos[agent]["live"][b]) == live, (b, agent)
        if not live:  # filler
            assert not v_obs[agent][b].any() and v_rew[agent][b] == 0.0
            assert not v_term[agent][b] and not v_trunc[agent][b]
            continue
        np.testing.assert_array_equal(v_obs[agent][b], observations[agent], err_msg=f"{b} {agent}")
        assert v_rew[agent][b] == rewards.get(agent, 0.0), (b, agent)
        assert bool(v_term[agent][b]) == terminations.get(agent, False), (b, agent)
        assert bool(v_trunc[agent][b]) == truncations.get(agent, False), (b, agent)
        for key in INFO_KEYS:
            assert v_infos[agent][key][b] == infos[agent][key], (b, agent, key)


def random_actions(rng: np.random.Generator, num_envs: int, agents: list[str]) -> dict:
    return {
        agent: rng.uniform((-0.5, -8.0), (0.5, 4.0), (num_envs, 2)).astype(np.float32)
        for agent in agents
    }


@pytest.mark.parametrize("name", list(VERSIONS))
def test_expert_driven_scenes_equal_single_envs_through_an_autoreset(name):
    module = ENV_MODULES[name]
    case_names = VERSIONS[name].scenario_class.case_names
    cases = [case_names[b % 2] for b in range(3)]
    vector = module.vector_env(3, case=cases, max_cycles=8)
    singles = Singles(module, cases, seed=40, max_cycles=8)
    observations, infos = vector.reset(seed=40)
    zeros = {agent: np.zeros(3) for agent in vector.possible_agents}
    nothing = {agent: np.zeros(3, dtype=bool) for agent in vector.possible_agents}
    for b in range(3):
        first = (observations, zeros, nothing, nothing, infos)
        assert_scene_equal(first, singles.first[b], b, reset=True)
    for _ in range(20):  # two autoresets per scene
        actions = vector.expert_actions()
        result = vector.step(actions)
        for b in range(3):
            single, reset = singles.step(b, {agent: a[b] for agent, a in actions.items()})
            assert_scene_equal(result, single, b, reset)
    np.testing.assert_array_equal(vector.episode_seeds, [env.episode_seed for env in singles.envs])


@pytest.mark.parametrize("name", ["double_merge_v1", "halting_car_v3"])
def test_removed_cars_and_scenes_that_end_at_different_times(name):
    """Scenes 0 and 2 drive at random (cars collide and leave the road); in scenes 1 and 3
    every car steers hard towards its nearer road edge, so those scenes end early and restart
    while the others go on: every scene still equals its single environment, step by step."""
    module = ENV_MODULES[name]
    num_envs = 4
    vector = module.vector_env(num_envs)
    singles = Singles(module, [vector.default_cases[0]] * num_envs, seed=7)
    observations, _ = vector.reset(seed=7)
    rng = np.random.default_rng(3)
    restarts = np.zeros(num_envs, dtype=int)
    removed_seen = False
    for _ in range(70):
        actions = random_actions(rng, num_envs, vector.possible_agents)
        for agent, action in actions.items():
            edge = np.where(observations[agent][:, 1] > 7.0, 0.5, -0.5)  # ego y [m]
            action[1::2] = np.stack([edge[1::2], np.full(2, 4.0)], axis=1)
        result = vector.step(actions)
        observations = result[0]
        for b in range(num_envs):
            single, reset = singles.step(b, {agent: a[b] for agent, a in actions.items()})
            assert_scene_equal(result, single, b, reset)
            restarts[b] += reset
        live = vector.live
        removed_seen |= bool((~live[::2]).any() and live[::2].any())
    assert removed_seen  # some cars removed from a scene that went on
    assert restarts[1] > restarts[0] and restarts[3] > restarts[2]


def test_same_seeds_give_the_same_run_and_seed_lists_pick_scenes():
    runs = []
    for _ in range(2):
        env = halting_car_v3.vector_env(3)
        env.reset(seed=[5, 9, 5])
        steps = [env.step(env.expert_actions()) for _ in range(10)]
        runs.append(np.stack([step[0]["car_0"] for step in steps]))  # (10, B, D)
    np.testing.assert_array_equal(runs[0], runs[1])
    np.testing.assert_array_equal(runs[0][:, 0], runs[0][:, 2])  # scenes 0 and 2: seed 5
    assert not np.array_equal(runs[0][:, 0], runs[0][:, 1])
    env = halting_car_v3.vector_env(3)
    env.reset(seed=5)
    np.testing.assert_array_equal(env.episode_seeds, [5, 6, 7])
    env.reset()  # each scene's sequence goes on, as a single environment's reset()
    single = halting_car_v3.parallel_env()
    single.reset(seed=6)
    single.reset()
    assert env.episode_seeds[1] == single.episode_seed


def test_spaces_and_observations_inside_them():
    env = halting_car_v3.vector_env(4)
    assert env.single_observation_space("car_0").shape == (109,)
    assert env.observation_space("car_0").shape == (4, 109)
    assert env.single_action_space("car_3").shape == (2,)
    assert env.action_space("car_3").shape == (4, 2)
    observations, _ = env.reset(seed=1, options={"case": ["stop", "go", "go", "stop"]})
    assert env.cases == ["stop", "go", "go", "stop"]
    for _ in range(5):
        observations, *_ = env.step(env.expert_actions())
    for agent, value in observations.items():
        assert value.dtype == np.float32 and env.observation_space(agent).contains(value)
    frame = env.render(2)
    assert frame.shape == (200, 800, 3) and frame.dtype == np.uint8


def test_actions_as_one_array_equal_actions_per_agent():
    results = []
    for as_array in (False, True):
        env = halting_car_v3.vector_env(2)
        env.reset(seed=3)
        actions = env.expert_actions()
        if as_array:
            actions = np.stack([actions[agent] for agent in env.possible_agents], axis=1)
        results.append(env.step(actions)[0])
    for agent in results[0]:
        np.testing.assert_array_equal(results[0][agent], results[1][agent])


def test_bad_actions_are_refused_naming_scene_and_car_and_nothing_moves():
    env = halting_car_v3.vector_env(4)
    env.reset(seed=0)
    before = env.scenes.world.state
    good = env.expert_actions()

    def refused(actions, error, pattern):
        with pytest.raises(error, match=pattern):
            env.step(actions)
        np.testing.assert_array_equal(env.scenes.world.state, before)

    nan = {**good, "car_5": good["car_5"].copy()}
    nan["car_5"][3] = (np.nan, 0.0)
    refused(
        nan,
        ValueError,
        r"^action of car_5 in scene 3 must be 2 finite numbers \[steering rad, acceleration "
        r"m/s\^2\], shape \(2,\); got .*: non-finite values$",
    )
    refused({**good, "car_2": np.zeros((3, 2))}, ValueError, r"action of car_2 must be a \(4, 2\)")
    refused({**good, "car_2": np.full((4, 2), "a")}, ValueError, "action of car_2 .* dtype <U1")
    missing = {agent: a for agent, a in good.items() if agent != "car_7"}
    refused(missing, ValueError, r"missing \['car_7'\]$")
    refused({**good, "car_99": good["car_0"]}, ValueError, r"unknown agents \['car_99'\]$")
    refused([good], TypeError, "actions must be a dict")
    refused(np.zeros((4, 22, 3)), ValueError, r"real \(4, 22, 2\) array")


def test_a_removed_agents_actions_are_ignored():
    env = halting_car_v3.vector_env(2)
    env.reset(seed=2, options={"case": "stop"})
    actions = env.expert_actions()
    while env.live[1, 0]:  # scene 1's follower floors it into the leader: both are removed
        actions = env.expert_actions()
        actions["car_0"] = actions["car_0"].copy()
        actions["car_0"][1] = (0.0, 4.0)
        _, _, terminations, _, infos = env.step(actions)
    assert terminations["car_0"][1] and infos["car_0"]["collided"][1]
    assert not env.live[1, :2].any() and env.live[0].all()
    actions = env.expert_actions()
    actions["car_1"] = actions["car_1"].copy()
    actions["car_1"][1] = np.nan  # removed: ignored
    observations, rewards, *_, infos = env.step(actions)
    assert not infos["car_1"]["live"][1] and infos["car_1"]["live"][0]
    assert not observations["car_1"][1].any() and rewards["car_1"][1] == 0.0


def test_bad_arguments():
    with pytest.raises(ValueError, match="num_envs must be an integer of at least 1"):
        halting_car_v3.vector_env(0)
    with pytest.raises(ValueError, match="case must be one case or 2 cases"):
        halting_car_v3.vector_env(2, case=["stop"])
    with pytest.raises(ValueError, match="unknown case"):
        halting_car_v3.vector_env(2, case="major")
    env = halting_car_v3.vector_env(2)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(env.possible_agents)
    with pytest.raises(ValueError, match="seed must be an int, 2 ints or None"):
        env.reset(seed=[1, 2, 3])
    with pytest.warns(UserWarning, match=r"unknown options \['cse'\]"):
        env.reset(seed=0, options={"cse": "go"})
    with pytest.warns(UserWarning, match="latest version"):
        assert ScenarioVectorEnv("halting_car", 1).version is FAMILIES["halting_car"][-1]
