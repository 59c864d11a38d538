"""The PettingZoo environments: PettingZoo's own checkers, then what those checkers miss
(multi-step determinism, observations inside their space over whole episodes, agents that
terminate early), equality with `rollout`, pickling, random actions, input errors."""

from __future__ import annotations

import pickle
import re
import types
import warnings
from collections.abc import Iterator

import numpy as np
import pytest

# Importing pettingzoo.test runs `from pettingzoo.classic import connect_four_v3` (in its
# api_test module), and PettingZoo's own classic envs warn that their old creation API is
# deprecated. That warning is about PettingZoo's code, not ours: silence it here, at import only.
with warnings.catch_warnings():
    warnings.filterwarnings(
        "ignore", "The old environment creation API", DeprecationWarning, "pettingzoo"
    )
    from pettingzoo.test import (
        api_test,
        max_cycles_test,
        parallel_api_test,
        parallel_seed_test,
        render_test,
        seed_test,
    )

from scenarios import (
    ENV_MODULES,
    VERSIONS,
    DoubleMergeConfig,
    double_merge_v0,
    halting_car_v0,
    rollout,
)
from scenarios.junction import JunctionScenario

MODULES = [ENV_MODULES[name] for name in VERSIONS]  # every registered version's module
CASES = [
    (module, case)
    for module in MODULES
    for case in module.raw_env.version.scenario_class.case_names
]
IDS = [f"{module.__name__.split('.')[-1]}-{case}" for module, case in CASES]


def scenario_of(module):
    """The scenario (plain class, the version's settings) that `module`'s environment serves."""
    return module.raw_env.version.make()


def seeded(factory, seed: int = 0):
    """A factory whose environments are already seeded (reset and action spaces), so that the
    checkers, which reset without a seed and sample actions, run the same way every time."""

    def make(**kwargs):
        env = factory(**kwargs)
        env.reset(seed=seed)
        for index, agent in enumerate(env.possible_agents):
            env.action_space(agent).seed(seed + index)
        return env

    return make


def run_episode(env, seed: int, case: str, policy) -> list[tuple]:
    """Step until every agent is done; returns the per-step (obs, rew, term, trunc, info)."""
    observations, infos = env.reset(seed=seed, options={"case": case})
    history = [(observations, infos)]
    while env.agents:
        history.append(env.step(policy(env, observations)))
        observations = history[-1][0]
    return history


def expert(env, observations):
    return env.unwrapped.expert_actions()


def random_policy(env, observations):
    return {agent: env.action_space(agent).sample() for agent in env.agents}


def assert_same(first, second) -> None:
    """Recursive equality of dicts/tuples/lists of arrays and scalars."""
    if isinstance(first, dict):
        assert first.keys() == second.keys()
        for key in first:
            assert_same(first[key], second[key])
    elif isinstance(first, (tuple, list)):
        assert len(first) == len(second)
        for a, b in zip(first, second):
            assert_same(a, b)
    elif isinstance(first, np.ndarray):
        assert first.dtype == second.dtype
        np.testing.assert_array_equal(first, second)
    else:
        assert first == second and type(first) is type(second)


# --- PettingZoo's checkers -------------------------------------------------------------------
@pytest.fixture
def no_warnings() -> Iterator[None]:
    """Fail the test if anything warns while it runs: the checkers report API problems as
    warnings, and our env must not warn about what they legitimately pass (their
    `reset(seed=0, options={"options": 1})` signature probe used to warn "unknown options")."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    assert [str(warning.message) for warning in caught] == []


@pytest.mark.parametrize("module", MODULES)
def test_parallel_api(module, no_warnings) -> None:
    parallel_api_test(seeded(module.parallel_env)(), num_cycles=200)


@pytest.mark.parametrize("module", MODULES)
def test_parallel_seed(module, no_warnings) -> None:
    parallel_seed_test(module.parallel_env)


@pytest.mark.parametrize("module", MODULES)
def test_aec_api(module, no_warnings) -> None:
    api_test(seeded(module.env)(), num_cycles=200)


@pytest.mark.parametrize("module", MODULES)
def test_aec_seed(module, no_warnings) -> None:
    seed_test(module.env)


@pytest.mark.parametrize("module", MODULES)
def test_render_modes(module, monkeypatch, no_warnings) -> None:
    pytest.importorskip("pygame")
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    render_test(seeded(module.env))


@pytest.mark.parametrize("module", MODULES)
def test_max_cycles(module, no_warnings) -> None:
    max_cycles_test(
        types.SimpleNamespace(parallel_env=seeded(module.parallel_env), env=seeded(module.env))
    )


# --- what the checkers miss --------------------------------------------------------------------
@pytest.mark.parametrize("policy", [expert, random_policy], ids=["expert", "random"])
@pytest.mark.parametrize(("module", "case"), CASES, ids=IDS)
def test_whole_episodes_are_deterministic_for_a_seed(module, case, policy) -> None:
    runs = []
    for _ in range(2):
        env = seeded(module.parallel_env, seed=3)()
        runs.append(run_episode(env, 21, case, policy))
    assert len(runs[0]) == len(runs[1]) > 2
    assert_same(runs[0], runs[1])


@pytest.mark.parametrize("policy", [expert, random_policy], ids=["expert", "random"])
@pytest.mark.parametrize(("module", "case"), CASES, ids=IDS)
def test_every_observation_is_inside_its_space(module, case, policy) -> None:
    env = seeded(module.parallel_env, seed=5)()
    for seed in range(3):
        for observations, *_ in run_episode(env, seed, case, policy):
            for agent, observation in observations.items():
                space = env.observation_space(agent)
                assert observation.dtype == np.float32
                assert space.contains(observation), (agent, observation)


@pytest.mark.parametrize(("module", "case"), CASES, ids=IDS)
def test_expert_steps_reproduce_rollout_exactly(module, case) -> None:
    scenario = scenario_of(module)
    env = module.parallel_env()
    for seed in (0, 17):
        episode = rollout(scenario, seed, case)
        env.reset(seed=seed, options={"case": case})
        for step in range(env.max_cycles):
            world = env.unwrapped.world
            np.testing.assert_array_equal(world.state.astype(np.float32), episode.states[step])
            actions = env.unwrapped.expert_actions()
            stacked = np.stack([actions[agent] for agent in env.possible_agents])
            np.testing.assert_array_equal(stacked, episode.actions[step])
            *_, infos = env.step(actions)
            # infos describe the new state: compare with the next recorded step
            if step + 1 < env.max_cycles:
                labels = [infos[agent]["attention"] for agent in env.possible_agents]
                np.testing.assert_array_equal(labels, episode.attention[step + 1])
                assert infos["car_0"]["interaction"] == episode.interaction[step + 1]
        assert env.agents == []


@pytest.mark.parametrize("module", MODULES)
def test_seedless_reset_reports_a_seed_that_rollout_replays(module) -> None:
    env = module.parallel_env()
    env.reset(seed=4)
    env.reset()
    seed, case = env.episode_seed, env.case
    assert seed != 4
    episode = rollout(scenario_of(module), seed, case)
    np.testing.assert_array_equal(env.world.state.astype(np.float32), episode.states[0])


def test_agents_that_crash_are_removed_for_good() -> None:
    """The follower floors it into the leader: both terminate, the rest go on to the end."""
    env = halting_car_v0.parallel_env()
    observations, _ = env.reset(seed=2, options={"case": "stop"})
    crash_step, frozen = None, None
    for step in range(env.max_cycles):
        actions = env.unwrapped.expert_actions()
        if "car_0" in actions:
            actions["car_0"] = np.array([0.0, 4.0], dtype=np.float32)
        observations, rewards, terminations, truncations, infos = env.step(actions)
        if crash_step is None and terminations.get("car_0"):
            crash_step, frozen = step, env.world.state[:2].copy()
            assert terminations["car_1"] and infos["car_1"]["collided"]
            assert rewards["car_0"] < -0.5 and infos["car_0"]["collided"]
            assert not any(terminations[f"car_{i}"] for i in range(2, 22))
            assert "car_0" not in env.agents and "car_1" not in env.agents
        elif crash_step is not None:
            assert "car_0" not in observations and "car_1" not in rewards
            assert "car_0" not in env.agents and "car_1" not in env.agents
            np.testing.assert_array_equal(env.world.state[:2], frozen)  # removed cars freeze
            # car_2's first two slots (car_0, car_1): presence 0 and zeros
            np.testing.assert_array_equal(observations["car_2"][4:14], 0.0)
            assert observations["car_2"][14] == 1.0  # car_3 is still there
            assert "car_0" not in env.unwrapped.expert_actions()
    assert crash_step is not None and crash_step < env.max_cycles - 5
    assert all(truncations.values()) and len(truncations) == 20
    assert env.agents == []


def test_leaving_the_road_terminates_only_that_agent() -> None:
    env = double_merge_v0.parallel_env()
    env.reset(seed=1)
    lower_lane = [a for a in env.agents[2:] if env.world.xy[env.agent_index[a], 1] < 2.0][0]
    for _ in range(20):
        actions = env.unwrapped.expert_actions()
        actions[lower_lane] = np.array([-0.3, 0.0], dtype=np.float32)  # steer off the right edge
        _, rewards, terminations, _, infos = env.step(actions)
        if terminations[lower_lane]:
            break
    assert infos[lower_lane]["off_road"] and not infos[lower_lane]["collided"]
    assert rewards[lower_lane] < -0.5
    assert sum(terminations.values()) == 1 and lower_lane not in env.agents


def test_observation_layout_matches_the_documented_table() -> None:
    env = double_merge_v0.parallel_env()
    observations, _ = env.reset(seed=6, options={"case": "minor"})
    state = env.world.state  # (N, 4)
    obs = observations["car_1"]
    assert obs.shape == (4 + 5 * 21,)
    np.testing.assert_allclose(obs[:4], state[1], rtol=1e-6)
    # car_1's first "other" slot is car_0, its second is car_2
    np.testing.assert_allclose(obs[4:9], [1.0, *(state[0] - state[1])], rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(obs[9:14], [1.0, *(state[2] - state[1])], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("module", MODULES)
def test_pickle_round_trip_mid_episode(module) -> None:
    env = seeded(module.parallel_env, seed=1)(render_mode="rgb_array")
    env.reset(seed=9)
    for _ in range(5):
        env.step(env.unwrapped.expert_actions())
    clone = pickle.loads(pickle.dumps(env))
    assert clone.agents == env.agents and clone.num_cycles == env.num_cycles
    for _ in range(10):
        original = env.step(env.unwrapped.expert_actions())
        copied = clone.step(clone.unwrapped.expert_actions())
        assert_same(original, copied)
    np.testing.assert_array_equal(clone.render(), env.render())


@pytest.mark.parametrize(("module", "case"), CASES, ids=IDS)
def test_random_and_extreme_actions_never_crash(module, case) -> None:
    env = seeded(module.parallel_env, seed=8)()
    for seed in range(4):
        run_episode(env, seed, case, random_policy)
    corners = [np.array(c, dtype=np.float32) for c in ([-0.5, -8.0], [0.5, 4.0], [9.0, 99.0])]

    def extreme(env, observations):
        return {agent: corners[i % 3] for i, agent in enumerate(env.agents)}

    history = run_episode(env, 0, case, extreme)
    assert len(history) > 1


def test_driving_one_car_while_the_expert_drives_the_rest() -> None:
    env = double_merge_v0.parallel_env()
    env.reset(seed=3, options={"case": "major"})  # car_0 (green) is the rear car
    while env.agents:
        actions = env.unwrapped.expert_actions()
        assert set(actions) == set(env.agents)
        actions["car_0"] = np.array([0.0, 0.0], dtype=np.float32)  # it just keeps its lane
        _, _, terminations, _, infos = env.step(actions)
        assert not any(terminations.values())
    # the front car merged; the rear one (driven by us) did not
    assert abs(env.world.xy[1, 1] - env.world.xy[0, 1]) < 0.1


@pytest.mark.parametrize("module", MODULES)
def test_aec_env_drives_with_the_expert_through_unwrapped(module) -> None:
    env = module.env()
    env.reset(seed=1)
    steps = 0
    for agent in env.agent_iter():
        _, _, terminated, truncated, _ = env.last()
        if terminated or truncated:
            action = None
        else:
            action = env.unwrapped.expert_actions()[agent]
        env.step(action)
        steps += 1
    # every cycle, then one last turn each to be removed (Double Merge, Halting Car: 22 x 61)
    config = env.unwrapped.config
    assert steps == config.num_cars * (config.num_steps + 1)
    assert env.unwrapped.world.active.all()  # nobody crashed


def test_infos_carry_roles_labels_and_interaction() -> None:
    env = halting_car_v0.parallel_env()
    history = run_episode(env, 0, "stop", expert)
    infos = history[0][1]
    assert infos["car_0"]["role"] == "main_green" and infos["car_1"]["role"] == "main_brown"
    assert {infos[f"car_{i}"]["role"] for i in range(2, 22)} == {"distractor"}
    assert infos["car_0"]["attention"] == 1 and infos["car_1"]["attention"] == -1
    flags = [step[-1]["car_0"]["interaction"] for step in history[1:]]
    assert any(flags) and not all(flags)


def test_bad_arguments_and_calls_are_refused_with_clear_errors() -> None:
    env = double_merge_v0.parallel_env()
    with pytest.raises(RuntimeError, match="reset"):
        env.step({})
    with pytest.raises(ValueError, match="unknown case"):
        env.reset(seed=0, options={"case": "stop"})
    with pytest.raises(ValueError, match="unknown case"):
        double_merge_v0.parallel_env(case="sideways")
    with pytest.raises(ValueError, match="render_mode"):
        double_merge_v0.parallel_env(render_mode="ansi")
    with pytest.raises(ValueError, match="max_cycles"):
        double_merge_v0.parallel_env(max_cycles=0)
    with pytest.raises(TypeError, match="options must be a dict"):
        env.reset(seed=0, options="minor")


def test_unknown_reset_options_warn_but_the_checker_probe_does_not() -> None:
    env = double_merge_v0.parallel_env()
    with pytest.warns(UserWarning, match=r"unknown options \['cse'\]") as caught:
        env.reset(seed=0, options={"cse": "minor", "options": 1})
    assert len(caught) == 1 and env.case == "major"  # the typo fell back to the default case
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.reset(seed=0, options={"options": 1, "case": "minor"})
    assert env.case == "minor"


BAD_ACTIONS = {
    "string": ("left", "not real numbers"),
    "strings": (["a", "b"], "not real numbers"),
    "numeric strings": (["0.1", "0"], "not real numbers"),
    "None": (None, "not real numbers"),
    "booleans": ([True, False], "not real numbers"),
    "complex": ([1j, 0.0], "not real numbers"),
    "scalar": (0.5, r"shape \(\)"),
    "too short": ([0.1], r"shape \(1,\)"),
    "too long": (np.zeros(3), r"shape \(3,\)"),
    "nested": ([[0.1, 2.0]], r"shape \(1, 2\)"),
    "NaN": ([np.nan, 0.0], "non-finite"),
    "infinite": (np.array([0.0, -np.inf], dtype=np.float32), "non-finite"),
}


@pytest.mark.parametrize(("action", "problem"), BAD_ACTIONS.values(), ids=BAD_ACTIONS.keys())
def test_a_bad_action_is_refused_naming_the_car_and_nothing_moves(action, problem) -> None:
    env = double_merge_v0.parallel_env()
    env.reset(seed=0)
    before = env.world.state.copy()
    actions = env.unwrapped.expert_actions()
    actions["car_3"] = action
    with pytest.raises(ValueError, match=problem) as error:
        env.step(actions)
    message = str(error.value)
    assert message.startswith("action of car_3 must be 2 finite numbers")
    assert "[steering rad, acceleration m/s^2], shape (2,)" in message
    assert env.num_cycles == 0 and env.agents == env.possible_agents
    np.testing.assert_array_equal(env.world.state, before)


def test_good_actions_of_any_real_dtype_are_accepted_alike() -> None:
    runs = []
    for to_action in (
        lambda a: a,
        lambda a: a.astype(np.float64),
        lambda a: a.tolist(),
        lambda a: tuple(float(v) for v in a),
    ):
        env = double_merge_v0.parallel_env()
        env.reset(seed=0)
        actions = {agent: to_action(a) for agent, a in env.unwrapped.expert_actions().items()}
        actions["car_3"] = np.array([0, 1], dtype=np.int64)  # integers are numbers too
        runs.append(env.step(actions))
    for run in runs[1:]:
        assert_same(run, runs[0])


def test_the_action_dict_must_name_exactly_the_live_agents() -> None:
    env = halting_car_v0.parallel_env()
    env.reset(seed=2, options={"case": "stop"})
    actions = env.unwrapped.expert_actions()
    with pytest.raises(TypeError, match="actions must be a dict .* got list"):
        env.step([[0.0, 0.0]] * 22)
    with pytest.raises(ValueError, match=r"missing \['car_3'\]$"):
        env.step({agent: action for agent, action in actions.items() if agent != "car_3"})
    with pytest.raises(ValueError, match=r"unknown agents \['car_99', 'green'\]$"):
        env.step({**actions, "car_99": [0.0, 0.0], "green": [0.0, 0.0]})
    while "car_0" in env.agents:  # the follower floors it into the leader: both are removed
        actions = env.unwrapped.expert_actions()
        actions["car_0"] = np.array([0.0, 4.0], dtype=np.float32)
        env.step(actions)
    with pytest.raises(ValueError, match=r"no longer live \['car_0', 'car_1'\]$"):
        env.step({**env.unwrapped.expert_actions(), "car_0": [0.0, 0.0], "car_1": [0.0, 0.0]})


def test_metadata_is_never_written_from_an_instance() -> None:
    class_metadata = dict(double_merge_v0.raw_env.metadata)
    env = double_merge_v0.parallel_env(config=DoubleMergeConfig(record_every=1, num_steps=40))
    assert env.metadata["render_fps"] == pytest.approx(10.0)
    assert env.metadata is not double_merge_v0.raw_env.metadata
    assert double_merge_v0.raw_env.metadata == class_metadata
    assert env.max_cycles == 40
    assert double_merge_v0.parallel_env().metadata["render_fps"] == pytest.approx(5.0)
    assert halting_car_v0.parallel_env().metadata["render_fps"] == pytest.approx(10 / 3)


def on_junction(module) -> bool:
    return isinstance(scenario_of(module), JunctionScenario)


@pytest.mark.parametrize("module", MODULES)
def test_spaces_and_rendering(module) -> None:
    env = module.parallel_env(render_mode="rgb_array")
    env.reset(seed=0)
    num_cars = env.scenario.num_cars
    if not on_junction(module):  # the straight-road scenarios: 22 cars, a wide strip
        assert num_cars == 22
    for agent in env.possible_agents:
        space = env.observation_space(agent)
        assert space is env.observation_space(agent)
        assert space.dtype == np.float32 and np.isfinite(space.low).all()
        assert np.isfinite(space.high).all() and space.shape == (4 + 5 * (num_cars - 1),)
        action_space = env.action_space(agent)
        assert action_space.shape == (2,) and action_space.dtype == np.float32
        np.testing.assert_array_equal(action_space.low, [-0.5, -8.0])
    frame = env.render()
    size = (400, 400, 3) if on_junction(module) else (200, 800, 3)
    assert frame.shape == size and frame.dtype == np.uint8
    assert env.state().shape == (num_cars, 4)
    silent = module.parallel_env()
    silent.reset(seed=0)
    with pytest.warns(UserWarning, match="render_mode"):
        assert silent.render() is None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env.close()


TABLE_ROW = re.compile(
    r"^\s*\| (\d+)( \+ 5k)?\s+\|[^|]+\|\s*(-?pi|-?[\d.]+)\s*\|\s*(-?pi|-?[\d.]+)\s*\|$"
)


def documented_bound(text: str) -> float:
    """A Min or Max cell of the manual's observation table as a number ("-pi" included)."""
    return float(text.replace("pi", str(np.pi)))


@pytest.mark.parametrize("module", MODULES)
def test_the_manual_in_the_class_docstring_matches_the_spaces(module) -> None:
    env = module.parallel_env()
    manual = type(env).__doc__
    prose = " ".join(manual.split())  # the manual wraps its lines
    space, action_space = env.observation_space("car_0"), env.action_space("car_0")
    low, high = action_space.low.tolist(), action_space.high.tolist()
    assert f"`Box({low}, {high}, (2,), float32)` per agent" in prose
    assert f"`Box(float32, ({space.shape[0]},))` per agent" in prose
    others = env.scenario.num_cars - 1
    assert f"with k = 0 ... {others - 1} indexing the other {others} cars" in prose
    held = re.search(r"one env step = (\d) simulation steps of ([\d.]+) s \(([\d.]+) s\)", prose)
    assert int(held[1]) == env.config.record_every
    assert float(held[1]) * float(held[2]) == pytest.approx(float(held[3]))
    assert float(held[3]) == pytest.approx(env.config.recorded_dt)
    rows = [TABLE_ROW.match(line) for line in manual.splitlines()]
    rows = [row for row in rows if row]
    assert len(rows) == 9
    for row in rows:
        first = int(row[1])
        for index in [first, first + 5 * (others - 1)] if row[2] else [first]:
            assert space.low[index] == pytest.approx(documented_bound(row[3]), abs=1e-6)
            assert space.high[index] == pytest.approx(documented_bound(row[4]), abs=1e-6)
