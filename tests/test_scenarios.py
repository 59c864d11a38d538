"""Scenarios without PettingZoo: configs, recorded episodes, expert safety over 200 seeds per
case, the v0 scenarios' behaviour, and the causal dependence between the main cars (with a test
that distractors influence nobody). The registry of versions is in test_registry.py, the
reactive scenarios' behaviour (v1 to v3) in test_scenarios_reactive.py."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scenario_episodes import CASES, JUNCTIONS, STRAIGHT_CASES, episodes, plan_of, scenario

from carlo_lite import World, wrap_angle
from scenarios import (
    ROLE_NAMES,
    VERSIONS,
    DoubleMerge,
    DoubleMergeConfig,
    HaltingCar,
    HaltingCarConfig,
    ReactiveDoubleMergeConfig,
    ReactiveHaltingCarConfig,
    rollout,
)
from scenarios.base import BROWN, GREEN


# --- configuration ------------------------------------------------------------------------------
def test_class_attributes() -> None:
    assert DoubleMerge.case_names == ("major", "minor")
    assert HaltingCar.case_names == ("stop", "go")
    for version in VERSIONS.values():
        code = version.scenario_class
        assert code.default_major_case in code.case_names
        assert code.role_names == ROLE_NAMES == ("main_green", "main_brown", "distractor")
        assert version.make().name == version.name
    assert DoubleMerge.config_class is DoubleMergeConfig
    assert HaltingCar.config_class is HaltingCarConfig


@pytest.mark.parametrize(
    "config_class",
    [DoubleMergeConfig, HaltingCarConfig, ReactiveDoubleMergeConfig, ReactiveHaltingCarConfig],
)
def test_config_derived_quantities(config_class) -> None:
    config = config_class()
    assert config.num_steps <= 60
    assert config.num_observed + config.num_predicted == config.num_steps
    assert config.recorded_dt == pytest.approx(config.dt_sim * config.record_every, abs=1e-12)
    assert config.to_dict()["recorded_dt"] == config.recorded_dt
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.num_steps = 3


def test_config_values_of_the_documented_design() -> None:
    assert (DoubleMergeConfig().recorded_dt, HaltingCarConfig().recorded_dt) == (0.2, 0.3)
    assert (DoubleMergeConfig().num_observed, HaltingCarConfig().num_observed) == (15, 12)


def test_config_validation_and_case_errors() -> None:
    with pytest.raises(ValueError, match="brake_start_s"):
        HaltingCarConfig(brake_start_s=(5.0, 4.0))
    with pytest.raises(ValueError, match="num_observed"):
        DoubleMergeConfig(num_observed=60)
    with pytest.raises(ValueError, match="inner lanes"):
        HaltingCarConfig(main_lanes=(0,))
    with pytest.raises(TypeError):
        DoubleMerge(HaltingCarConfig())
    with pytest.raises(ValueError, match="unknown case"):
        rollout(DoubleMerge(), 0, "stop")


# --- recorded episodes --------------------------------------------------------------------------
@pytest.mark.parametrize(("name", "case"), CASES)
def test_episode_arrays_shapes_dtypes_and_first_state(name: str, case: str) -> None:
    sc = scenario(name)
    episode = rollout(sc, 3, case)
    steps, cars = sc.config.num_steps, sc.num_cars
    assert cars == (16 if name.startswith("left_turn") else 14 if name in JUNCTIONS else 22)
    assert episode.states.shape == (steps, cars, 4) and episode.states.dtype == np.float32
    assert episode.actions.shape == (steps, cars, 2) and episode.actions.dtype == np.float32
    assert episode.valid.shape == (steps, cars) and episode.valid.all()
    assert episode.attention.shape == (steps, cars) and episode.attention.dtype == np.int16
    assert episode.interaction.shape == (steps,) and episode.interaction.dtype == bool
    assert episode.roles.dtype == np.int8
    main = 4 if name.startswith("left_turn") else 2  # the turning car and 3 oncoming cars
    assert episode.roles.tolist() == [GREEN] + [BROWN] * (main - 1) + [2] * (cars - main)
    assert (episode.seed, episode.case, episode.scenario) == (3, case, name)
    assert episode.dt == sc.config.recorded_dt
    plan = plan_of(name, 3, case)
    np.testing.assert_array_equal(episode.states[0], plan.initial_state.astype(np.float32))


@pytest.mark.parametrize(("name", "case"), CASES)
def test_recorded_actions_reproduce_the_recorded_states(name: str, case: str) -> None:
    """Replaying the recorded actions (each held for record_every steps) on a fresh world gives
    back the recorded states: actions[t] is what was applied right after states[t]."""
    sc = scenario(name)
    episode = rollout(sc, 11, case)
    world = World(
        sc.road,
        episode.states[0, :, :2],
        episode.states[0, :, 2],
        episode.states[0, :, 3],
        dt=sc.config.dt_sim,
    )
    for step in range(sc.config.num_steps - 1):
        for _ in range(sc.config.record_every):
            world.step(episode.actions[step])
        state, recorded = world.state, episode.states[step + 1]
        np.testing.assert_allclose(state[:, [0, 1, 3]], recorded[:, [0, 1, 3]], atol=2e-4)
        turned = wrap_angle(state[:, 2] - recorded[:, 2])  # the same angle across -pi / pi
        np.testing.assert_allclose(turned, 0.0, atol=2e-4)


@pytest.mark.parametrize(("name", "case"), CASES)
def test_rollout_is_deterministic_over_whole_episodes(name: str, case: str) -> None:
    first, second = rollout(scenario(name), 5, case), rollout(VERSIONS[name].make(), 5, case)
    for field in ("states", "actions", "valid", "attention", "interaction"):
        np.testing.assert_array_equal(getattr(first, field), getattr(second, field))
    given = rollout(scenario(name), 5, case, rng=np.random.default_rng(5))
    np.testing.assert_array_equal(given.states, first.states)
    other = rollout(scenario(name), 6, case)
    assert not np.array_equal(other.states, first.states)


def test_rollout_leaves_global_random_state_alone() -> None:
    np.random.seed(123)
    expected = np.random.random()
    np.random.seed(123)
    rollout(scenario("double_merge_v0"), 0, "major")
    rollout(scenario("halting_car_v0"), 0, "stop")
    assert np.random.random() == expected


@pytest.mark.parametrize("name", list(VERSIONS))
def test_same_seed_gives_the_same_scene_in_every_case(name: str) -> None:
    cases = VERSIONS[name].scenario_class.case_names
    plans = [plan_of(name, 9, case) for case in cases]
    if name in JUNCTIONS:  # the case moves the main cars' timings; the rest of the scene stays
        distractors = scenario(name).roles == 2
        first, second = (plan.initial_state for plan in plans)
        np.testing.assert_array_equal(first[distractors], second[distractors])
        np.testing.assert_array_equal(first[GREEN], second[GREEN])
        return
    np.testing.assert_array_equal(plans[0].initial_state[2:], plans[1].initial_state[2:])
    xs = sorted(plans[0].initial_state[:2, 0])
    assert sorted(plans[1].initial_state[:2, 0]) == xs


# --- expert safety over 200 seeds per case ---------------------------------------------------
@pytest.mark.parametrize(("name", "case"), CASES)
def test_expert_never_collides_nor_leaves_the_road(name: str, case: str) -> None:
    runs = episodes(name, case)
    assert len(runs) >= 200
    assert not any(run.collided for run in runs)
    assert not any(run.off_road for run in runs)
    # randomised: initial gaps and speeds differ from seed to seed
    gaps = [np.linalg.norm(run.states[0, BROWN, :2] - run.states[0, GREEN, :2]) for run in runs]
    assert np.std(gaps) > 1.0
    assert len({round(float(run.states[0, 2, 3]), 6) for run in runs}) == len(runs)


@pytest.mark.parametrize(
    ("name", "case"), [(n, c) for n, c in STRAIGHT_CASES if n != "halting_car_v4"]
)
def test_distractors_drive_straight_at_constant_speed(name: str, case: str) -> None:
    for run in episodes(name, case)[:20]:
        distractors = run.states[:, 2:]  # (T, 20, 4)
        np.testing.assert_array_equal(run.actions[:, 2:], 0.0)
        np.testing.assert_array_equal(distractors[:, :, 1:], distractors[:1, :, 1:].repeat(60, 0))
        lanes = np.round(distractors[0, :, 1] / 3.5 - 0.5)
        assert set(lanes.tolist()) == {0.0, 3.0}


@pytest.mark.parametrize(("name", "case"), STRAIGHT_CASES)
def test_attention_labels(name: str, case: str) -> None:
    run = episodes(name, case)[0]
    expected = np.full(22, -1)
    if name.startswith("double_merge"):
        expected[GREEN], expected[BROWN] = BROWN, GREEN  # the paper's "Correct" oracle
    else:
        expected[GREEN] = BROWN  # the follower (green) watches the leader (brown)
    np.testing.assert_array_equal(run.attention, np.tile(expected, (60, 1)))


# --- Double Merge behaviour --------------------------------------------------------------------
@pytest.mark.parametrize("case", DoubleMerge.case_names)
def test_double_merge_main_cars_swap_lanes_and_the_rear_one_waits(case: str) -> None:
    config = DoubleMergeConfig()
    for run in episodes("double_merge_v0", case):
        start, end = run.states[0], run.states[-1]
        rear = GREEN if start[GREEN, 0] < start[BROWN, 0] else BROWN
        front = 1 - rear
        assert (rear == GREEN) == (case == "major")  # major: green starts behind brown
        assert abs(end[GREEN, 1] - start[BROWN, 1]) < 0.05
        assert abs(end[BROWN, 1] - start[GREEN, 1]) < 0.05
        toward = np.sign(start[front, 1] - start[rear, 1])
        rear_offset = (run.states[:, rear, 1] - start[rear, 1]) * toward  # (T,)
        front_error = np.abs(run.states[:, front, 1] - start[rear, 1])  # to its target lane
        waiting = np.nonzero(run.interaction)[0]
        assert len(waiting) > 0 and np.all(np.diff(waiting) == 1)  # one contiguous wait
        # while waiting the rear car holds a position next to the centre line ...
        held = rear_offset[waiting]
        assert held.min() > config.wait_offset_m[0] - 0.1
        assert held.max() < config.wait_offset_m[1] + 0.1
        # ... and it crosses the centre line only once the front car has settled
        crossing = np.argmax(rear_offset > 1.75)
        assert crossing > waiting[-1]
        assert front_error[: waiting[-1] + 1].min() < config.settled_lateral_tol_m
        # the decisive part (end of the wait, the merge) lies in the predicted steps
        assert waiting[-1] + 1 >= config.num_observed


def test_double_merge_wait_end_varies_from_episode_to_episode() -> None:
    ends = [np.nonzero(run.interaction)[0][-1] for run in episodes("double_merge_v0", "major")]
    assert np.std(ends) * 0.2 > 0.4  # seconds


# --- Halting Car behaviour ---------------------------------------------------------------------
def test_halting_car_stop_case_stops_waits_and_resumes() -> None:
    config = HaltingCarConfig()
    for run in episodes("halting_car_v0", "stop"):
        leader_speed = run.states[:, BROWN, 3]
        interaction = np.nonzero(run.interaction)[0]
        assert interaction[0] >= config.num_observed  # braking starts in the predicted part
        assert np.all(np.diff(interaction) == 1)
        stopped = np.nonzero(leader_speed == 0.0)[0]
        assert len(stopped) * config.recorded_dt >= config.stop_duration_s[0] - 0.3
        # flags describe the phase of the control chosen at that step: the last standing state
        # is the one from which the leader sets off again
        assert stopped[-1] == interaction[-1] + 1
        assert np.all(np.diff(leader_speed[interaction[0] : stopped[0] + 1]) < 0)
        assert abs(leader_speed[-1] - leader_speed[0]) < 0.05  # back at its cruising speed
        gap = run.states[:, BROWN, 0] - run.states[:, GREEN, 0] - config.car_length_m
        assert gap.min() > 1.0
        assert run.states[:, GREEN, 3].min() < 0.5 * run.states[0, GREEN, 3]  # it reacted


def test_halting_car_go_case_keeps_speed_and_has_no_interaction() -> None:
    for run in episodes("halting_car_v0", "go"):
        assert not run.interaction.any()
        np.testing.assert_allclose(run.states[:, BROWN, 3], run.states[0, BROWN, 3], atol=1e-5)
        assert run.states[:, GREEN, 3].min() > 0.6 * run.states[0, BROWN, 3]


# --- causal structure ---------------------------------------------------------------------------
def test_double_merge_rear_car_reacts_to_the_front_car_timing() -> None:
    sc = DoubleMerge()
    plan, other = plan_of("double_merge_v0", 1, "major"), plan_of("double_merge_v0", 2, "major")
    swapped = dataclasses.replace(
        plan,
        front_change_start_s=other.front_change_start_s,
        front_change_duration_s=other.front_change_duration_s,
    )
    assert abs(swapped.front_change_start_s - plan.front_change_start_s) > 0.2
    base, changed = rollout(sc, 1, "major", plan=plan), rollout(sc, 1, "major", plan=swapped)
    rear = plan.rear
    diverged = np.abs(base.states[:, rear] - changed.states[:, rear]).max(axis=1) > 0.05
    assert diverged.any()  # the rear car's own trajectory changes ...
    assert np.nonzero(base.interaction)[0][-1] != np.nonzero(changed.interaction)[0][-1]
    # ... only after its wait began: its own past could not have told
    assert np.argmax(diverged) > np.nonzero(base.interaction)[0][0]


def test_double_merge_rear_car_keeps_waiting_if_the_front_car_never_moves() -> None:
    sc = DoubleMerge()
    base = rollout(sc, 4, "minor")
    front = GREEN  # minor: green starts ahead
    forced = np.full_like(base.actions, np.nan)
    forced[:, front] = (0.0, 0.0)  # front car keeps its lane (and its speed)
    held = rollout(sc, 4, "minor", forced_actions=forced)
    assert not held.collided
    waiting = np.nonzero(held.interaction)[0]
    assert waiting[-1] == 59  # still waiting at the end
    rear_lane_y = base.states[0, BROWN, 1]
    assert np.abs(held.states[:, BROWN, 1] - rear_lane_y).max() < 1.0  # never crossed


@pytest.mark.parametrize(("name", "case"), CASES)
def test_distractors_influence_nobody(name: str, case: str) -> None:
    sc = VERSIONS[name].make()
    base = rollout(sc, 8, case)
    forced = np.full_like(base.actions, np.nan)
    forced[:, 5] = (0.05, -2.0)  # one distractor swerves and brakes (and may leave the road)
    perturbed = rollout(sc, 8, case, forced_actions=forced)
    assert not np.allclose(perturbed.states[:, 5], base.states[:, 5])
    np.testing.assert_array_equal(perturbed.states[:, :2], base.states[:, :2])
    np.testing.assert_array_equal(perturbed.actions[:, :2], base.actions[:, :2])


def test_halting_car_follower_reacts_to_the_leader_timing() -> None:
    sc = HaltingCar()
    plan, other = plan_of("halting_car_v0", 1, "stop"), plan_of("halting_car_v0", 7, "stop")
    swapped = dataclasses.replace(
        plan, brake_start_s=other.brake_start_s, brake_decel_mps2=other.brake_decel_mps2
    )
    assert abs(swapped.brake_start_s - plan.brake_start_s) > 0.3
    base, changed = rollout(sc, 1, "stop", plan=plan), rollout(sc, 1, "stop", plan=swapped)
    follower_change = np.abs(base.states[:, GREEN] - changed.states[:, GREEN]).max(axis=1)
    leader_change = np.abs(base.states[:, BROWN] - changed.states[:, BROWN]).max(axis=1)
    assert follower_change.max() > 1.0
    # the follower departs from its old trajectory only after the leader did
    assert np.argmax(follower_change > 1e-6) > np.argmax(leader_change > 1e-6)


def test_halting_car_follower_brakes_for_a_leader_forced_to_stop() -> None:
    sc = HaltingCar()
    base = rollout(sc, 2, "go")
    forced = np.full_like(base.actions, np.nan)
    forced[20:, BROWN] = (0.0, -5.0)  # the leader brakes hard from 6 s on
    braked = rollout(sc, 2, "go", forced_actions=forced)
    assert not braked.collided
    assert braked.states[-1, GREEN, 3] < 0.5 and base.states[-1, GREEN, 3] > 5.0
    np.testing.assert_array_equal(braked.states[:21, GREEN], base.states[:21, GREEN])


def test_forced_actions_shape_is_checked() -> None:
    with pytest.raises(ValueError, match="forced_actions"):
        rollout(DoubleMerge(), 0, "major", forced_actions=np.zeros((3, 22, 2)))


# --- Halting Car v4: braking distractors ---------------------------------------------------------
@pytest.mark.parametrize("case", HaltingCar.case_names)
def test_halting_car_v4_distractors_brake_per_lane_and_the_main_cars_are_v3s(case: str) -> None:
    """Each outer lane's distractors brake and resume together (their gaps never change, every
    lane brakes in every scene), and the main cars drive exactly as in v3 with the same seed."""
    for run in episodes("halting_car_v4", case)[:30]:
        distractors = run.states[:, 2:]  # (T, 20, 4)
        np.testing.assert_array_equal(distractors[:, :, 1:3], distractors[:1, :, 1:3].repeat(60, 0))
        for lane_y in np.unique(distractors[0, :, 1]):
            column = distractors[:, distractors[0, :, 1] == lane_y]  # (T, 10, 4)
            gaps = np.diff(column[:, :, 0], axis=1)
            np.testing.assert_allclose(gaps, gaps[:1].repeat(60, 0), atol=1e-3)
            assert column[:, 0, 3].min() < 0.5 * column[0, 0, 3] + 1e-6  # it brakes hard
    v3, v4 = (
        rollout(scenario("halting_car_v3"), 4, case),
        rollout(scenario("halting_car_v4"), 4, case),
    )
    np.testing.assert_array_equal(v3.states[:, :2], v4.states[:, :2])
    np.testing.assert_array_equal(v3.attention, v4.attention)
